"""The layers hold: core, online, bag I/O, the pipeline, datasets and the bag tools import without
rclpy."""

from __future__ import annotations

import subprocess
import sys

MODULES = (
    'pearl_ros.core',
    'pearl_ros.core.config',
    'pearl_ros.online',
    'pearl_ros.bagio.reader',
    'pearl_ros.bagio.writer',
    'pearl_ros.bagio.decode',
    'pearl_ros.bagio.encode',
    'pearl_ros.datasets.hopkins',
    'pearl_ros.online.segmenter',
    'pearl_ros.datasets.synthetic',
    'pearl_ros.cli.make_bag',
    'pearl_ros.cli.segment_bag',
    'pearl_ros.pipeline',
    'pearl_ros.pipeline.settings',
    'pearl_ros.pipeline.messages',
    'pearl_ros.pipeline.replay',
    'pearl_ros.cli.replay',
    'pearl_ros.cli.bench',
    'pearl_ros.cli.bench_stream',
    'pearl_ros.cli.bench_sets',
    'pearl_ros.cli.score',
    'pearl_ros.scoring',
    'pearl_ros.evaluation.sets',
    'pearl_ros.datasets.adelaide',
    'pearl_ros.datasets.kt3dmoseg',
    'pearl_ros.datasets.outliers',
    'pearl_ros.datasets.robot',
    'pearl_ros.core.models.ego',
    'pearl_ros.pipeline.poses',
)

# A finder first on sys.meta_path records every attempt to import ROS client code, so even an
# import guarded by try/except ImportError (where rclpy is not installed) is caught.
PROGRAM = f"""
import importlib, sys
attempts = []
class Tripwire:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('rclpy', 'rosidl_runtime_py', 'sensor_msgs', 'std_msgs',
                                  'geometry_msgs', 'nav_msgs'):
            attempts.append(name)
        return None
sys.meta_path.insert(0, Tripwire())
for name in {MODULES!r}:
    importlib.import_module(name)
assert 'rclpy' not in sys.modules, 'rclpy imported'
assert not attempts, attempts
print('ok')
"""


def test_ros_free_layers_import_without_rclpy() -> None:
    done = subprocess.run(
        [sys.executable, '-c', PROGRAM], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == 'ok'


def test_the_tripwire_catches_a_guarded_rclpy_import() -> None:
    # The check above must be able to fail: a module that tries rclpy trips it.
    program = PROGRAM.replace("print('ok')", '') + (
        '\ntry:\n    import rclpy\nexcept ImportError:\n    pass\n'
        # rclpy is installed (the node needs it): importing it also imports its submodules.
        "assert attempts[:1] == ['rclpy'], attempts\nprint('tripped')\n"
    )
    done = subprocess.run(
        [sys.executable, '-c', program], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == 'tripped'
