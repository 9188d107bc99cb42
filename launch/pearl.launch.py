"""Launch pearl_node behind a feature tracker, for ROS 2 installs with launch and launch_ros.

    ros2 launch pearl_ros pearl.launch.py
    ros2 launch pearl_ros pearl.launch.py features:=/my_tracker/features \
        params_file:=/path/to/my_pearl.yaml

The node reads ``features`` (remapped here to the VINS-Mono tracker's topic) and publishes
``motion_labels`` and ``static_features`` in ``namespace``. Feed ``static_features`` to the
estimator in place of the tracker's topic (for VINS-Mono, remap the estimator's
``/feature_tracker/feature`` input to ``/static_features``).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    defaults = os.path.join(get_package_share_directory('pearl_ros'), 'config', 'pearl.yaml')
    return LaunchDescription([
        DeclareLaunchArgument(
            'features', default_value='/feature_tracker/feature',
            description='tracked-feature topic of the front end (PointCloud or PointCloud2)'),
        DeclareLaunchArgument(
            'params_file', default_value=defaults,
            description='parameters file (defaults: config/pearl.yaml of this package)'),
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='namespace of the node and of its outputs'),
        Node(
            package='pearl_ros',
            executable='pearl_node',
            name='pearl_node',
            namespace=LaunchConfiguration('namespace'),
            output='screen',
            parameters=[LaunchConfiguration('params_file')],
            remappings=[('features', LaunchConfiguration('features'))],
        ),
    ])
