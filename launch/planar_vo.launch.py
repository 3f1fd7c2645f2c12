"""Start planar_vo_node with the shipped parameters, remapped to a camera's topics.

    ros2 launch planar_vo planar_vo.launch.py image:=/camera/image_raw \
        camera_info:=/camera/camera_info [namespace:=robot] [image_transport:=compressed] \
        [params_file:=my_robot.yaml] [use_sim_time:=true]

With ``image_transport:=compressed`` the node subscribes ``<image>/compressed``.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    """The launch arguments and the one node."""
    arguments = [
        DeclareLaunchArgument(
            'params_file',
            default_value=PathJoinSubstitution(
                [FindPackageShare('planar_vo'), 'config', 'planar_vo.yaml']),
            description='ROS 2 params YAML (planar_vo: ros__parameters:); the camera mounting '
                        'in it must be your robot\'s'),
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of the node and its topics'),
        DeclareLaunchArgument('image', default_value='image',
                              description='camera image topic (sensor_msgs/Image)'),
        DeclareLaunchArgument('camera_info', default_value='camera_info',
                              description='CameraInfo topic of that camera'),
        DeclareLaunchArgument('image_transport', default_value='raw',
                              choices=['raw', 'compressed'],
                              description="'compressed' subscribes <image>/compressed"),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              choices=['true', 'false'],
                              description='use /clock (bag playback, simulation)'),
    ]
    node = Node(
        package='planar_vo',
        executable='planar_vo_node',
        name='planar_vo',
        namespace=LaunchConfiguration('namespace'),
        output='screen',
        parameters=[
            LaunchConfiguration('params_file'),
            {'image_transport': LaunchConfiguration('image_transport'),
             'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'),
                                            value_type=bool)},
        ],
        remappings=[('image', LaunchConfiguration('image')),
                    ('camera_info', LaunchConfiguration('camera_info'))],
    )
    return LaunchDescription([*arguments, node])
