"""Every console script of setup.py answers --help with its usage and exit status 0."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
# 'pearl_node = pearl_ros.ros.node:main' lines of setup.py's console_scripts.
SCRIPTS = re.findall(r"'(\w+) = [\w.]+:\w+'", (REPO / 'setup.py').read_text())


def test_setup_py_lists_the_console_scripts() -> None:
    assert {'pearl_node', 'pearl_replay', 'pearl_bench', 'pearl_play'} <= set(SCRIPTS)


# argparse answers -h as --help; pearl_node parses its arguments itself.
@pytest.mark.parametrize(('script', 'flag'), [*((s, '--help') for s in SCRIPTS),
                                              ('pearl_node', '-h')])
def test_every_console_script_prints_its_usage_and_exits_0(script: str, flag: str) -> None:
    executable = BIN / script
    assert executable.is_file(), f'{executable} missing: pip install -e . (make venv)'
    done = subprocess.run([str(executable), flag], capture_output=True, text=True, timeout=60,
                          stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f'usage: {script}'), done.stdout[:200]
    assert done.stderr == ''
