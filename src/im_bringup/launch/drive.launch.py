"""Jazzy launch file: the four drive nodes as separate processes, one parameters YAML.

    ros2 launch im_bringup drive.launch.py [params_file:=/path/to/params.yaml]

The default YAML is the position task with the min-energy strategy (generate another with
``ros2 run im_bringup scenario --task speed --strategy min_loss --write-params my.yaml``).
Record the running graph with ``ros2 run im_bringup record --out bags/run.mcap``.
Needs a full ROS 2 Jazzy install (``launch``/``launch_ros`` are not on PyPI); nothing in the test
suite imports this file.
"""
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    params = LaunchConfiguration('params_file')
    default = PathJoinSubstitution([FindPackageShare('im_bringup'), 'config', 'drive.yaml'])
    nodes = [('im_plant', 'plant'), ('im_controller', 'controller'),
             ('im_observer', 'observer'), ('im_adapt', 'adapter')]
    return LaunchDescription(
        [DeclareLaunchArgument('params_file', default_value=default,
                               description='ROS 2 parameters YAML for plant, controller, '
                                           'observer and adapter')]
        + [Node(package=pkg, executable=exe, name=exe, parameters=[params], output='screen')
           for pkg, exe in nodes])
