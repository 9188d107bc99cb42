"""Install pearl_ros: colcon (ament_python) on a ROS 2 install, or pip in a venv."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'pearl_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    python_requires='>=3.10',
    install_requires=['setuptools', 'numpy', 'scipy', 'PyMaxflow', 'rosbags', 'ruamel.yaml',
                      'opencv-python-headless'],
    zip_safe=True,
    maintainer='pearl_ros maintainers',
    maintainer_email='maintainers@pearl-ros.invalid',
    description='Online multi-body motion segmentation of tracked features with PEaRL.',
    license='GPL-3.0-or-later',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'pearl_make_bag = pearl_ros.cli.make_bag:main',
            'pearl_bench = pearl_ros.cli.bench:main',
            'pearl_segment_bag = pearl_ros.cli.segment_bag:main',
            'pearl_node = pearl_ros.ros.node:main',
            'pearl_tracker = pearl_ros.ros.tracker_node:main',
            'pearl_node_bench = pearl_ros.ros.bench:main',
            'pearl_play = pearl_ros.ros.play:main',
            'pearl_replay = pearl_ros.cli.replay:main',
            'pearl_score = pearl_ros.cli.score:main',
            'pearl_video = pearl_ros.cli.video:main',
            'pearl_render = pearl_ros.cli.render:main',
        ],
    },
)
