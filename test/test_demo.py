"""``make demo`` on every bundled bag: the Makefile's own recipe, with real processes.

pearl_node starts in the background, pearl_play plays the bag into it live, pearl_replay writes
the output bag and pearl_score scores it. Make runs with the venv target taken as done (``-o
venv``: no reinstall from a test) and with this interpreter's scripts (``BIN``); pearl_play
plays as fast as the node answers (``DEMO_RATE=0``). Each bag gets a domain id of its own,
with discovery kept on this machine, so that other tests and other people's runs are not heard.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from bag_oracles import raw_messages

REPO = Path(__file__).resolve().parents[1]
BAGS = sorted(path.name for path in (REPO / 'bags').iterdir() if path.name != 'README.md')


def test_every_bundled_bag_is_in_the_demo() -> None:
    assert BAGS == ['1R2RCR', '1R2RCR_g12', '1R2RCR_g12_pair', '1R2RCR_g12_pc2',
                    '1R2RCR_g12_ros1.bag', 'cars2', 'synthetic_births_deaths']


@pytest.mark.skipif(shutil.which('make') is None, reason='make is not installed')
@pytest.mark.parametrize('bag', BAGS)
def test_make_demo_plays_scores_and_writes_every_bag(bag: str, tmp_path: Path) -> None:
    frames = len(raw_messages(REPO / 'bags' / bag, '/feature_tracker/feature'))
    out = tmp_path / 'demo_labels'
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           'ROS_DOMAIN_ID': str(1 + (os.getpid() + 7 * (1 + BAGS.index(bag))) % 100)}
    done = subprocess.run(
        ['make', '--no-print-directory', '-o', 'venv', 'demo',
         f'BIN={Path(sys.executable).parent}',
         f'DEMO_BAG=bags/{bag}', f'DEMO_OUT={out}', 'DEMO_RATE=0'],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=600, check=False)
    text = done.stdout + done.stderr
    assert done.returncode == 0, text
    assert 'Traceback' not in text and 'error' not in done.stderr, text
    assert f'\n{frames}/{frames} frames answered by pearl_node\n' in done.stdout
    assert 'The first frame has no labels' in done.stdout  # the legend
    lines = [line for line in done.stdout.splitlines() if line.startswith('frame ')]
    assert len(lines) == frames and lines[0].split()[3:5] == ['features', '0']
    assert '  error    n/a  ---' in lines[0]  # nothing labelled in frame 0
    assert all(line.endswith(' more') or '+' not in line for line in lines)
    # Ends with the output bag: what it holds and how to look at it.
    tail = done.stdout[done.stdout.index('pearl_replay: '):]
    assert f'wrote {out}: {frames} frames' in tail
    assert f'{out} is a ROS 2 bag; its topics (messages):' in tail
    assert f'  /motion_labels ({frames}): ' in tail and f'pearl_score {out}' in tail
    assert len(raw_messages(out, '/motion_labels')) == frames
