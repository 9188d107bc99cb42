"""From a camera to coloured motions: pearl_tracker and pearl_node on one camera's images.

For ROS 2 installs with launch and launch_ros:

    ros2 launch pearl_ros camera.launch.py image:=/camera/image_raw \
        camera_info:=/camera/camera_info
    ros2 launch pearl_ros camera.launch.py namespace:=front image:=/front/image_raw \
        camera_info:=/front/camera_info params_file:=/path/to/my_pearl.yaml
    ros2 launch pearl_ros camera.launch.py image:=/camera/image_raw \
        camera_info:=/camera/camera_info pose_topic:=/odometry/camera

In ``namespace``, ``pearl_tracker`` reads ``image`` and ``camera_info`` (remapped to the
launch arguments) and publishes ``features``; ``pearl_node`` segments ``features`` and, with
``image_topic`` set to the same image, publishes ``image_labels`` (the image with each feature
coloured by its motion) besides ``motion_labels`` and ``static_features``; it takes the lens
of ``camera_info`` (``camera_info_topic``) and segments the features undistorted. With
``pose_topic`` (the camera's odometry), ``pearl_node`` also takes the camera's poses, with the
intrinsics and lens of ``camera_info``: the static world becomes a motion of known
parameters. One camera per namespace: include this file once per camera for several.
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
            'image', default_value='/camera/image_raw',
            description='camera image topic (sensor_msgs/Image: mono8, mono16, bgr8, rgb8, '
                        'bgra8, rgba8)'),
        DeclareLaunchArgument(
            'camera_info', default_value='/camera/camera_info',
            description='camera_info topic of that camera (optional: without it the features '
                        'are in pixels)'),
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='namespace of both nodes and of their outputs'),
        DeclareLaunchArgument(
            'params_file', default_value=defaults,
            description='pearl_node parameters file (defaults: config/pearl.yaml of this '
                        'package)'),
        DeclareLaunchArgument(
            'pose_topic', default_value='',
            description="the camera optical frame's pose in a fixed world frame "
                        '(nav_msgs/Odometry; empty: none), with the intrinsics of camera_info'),
        DeclareLaunchArgument(
            'max_features', default_value='300',
            description='features the tracker keeps per image'),
        Node(
            package='pearl_ros',
            executable='pearl_tracker',
            name='pearl_tracker',
            namespace=LaunchConfiguration('namespace'),
            output='screen',
            parameters=[{'max_features': LaunchConfiguration('max_features')}],
            remappings=[('image', LaunchConfiguration('image')),
                        ('camera_info', LaunchConfiguration('camera_info'))],
        ),
        Node(
            package='pearl_ros',
            executable='pearl_node',
            name='pearl_node',
            namespace=LaunchConfiguration('namespace'),
            output='screen',
            # features: the tracker's output in the same namespace, no remapping needed
            parameters=[LaunchConfiguration('params_file'),
                        {'image_topic': LaunchConfiguration('image'),
                         'pose_topic': LaunchConfiguration('pose_topic'),
                         'camera_info_topic': LaunchConfiguration('camera_info')}],
            remappings=[],
        ),
    ])
