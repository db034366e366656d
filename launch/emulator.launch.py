"""Launch one valve emulator (a real ROS 2 install; launch is not on PyPI).

    ros2 launch pcv_sim emulator.launch.py
    ros2 launch pcv_sim emulator.launch.py namespace:=/left       # one valve per chamber:
    ros2 launch pcv_sim emulator.launch.py namespace:=/right      # run it twice
    ros2 launch pcv_sim emulator.launch.py params_file:=/path/to/my_emulator.yaml
    ros2 launch pcv_sim emulator.launch.py use_sim_time:=true        # follow a simulation's /clock
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory('pcv_sim'), 'config', 'emulator.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of the valve, e.g. /left (topics are relative)'),
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='ROS parameter file of the emulator node'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='true: the model follows /clock (e.g. Gazebo) instead of the wall clock'),
        Node(
            package='pcv_sim',
            executable='emulator',
            name='emulator',
            namespace=LaunchConfiguration('namespace'),
            parameters=[LaunchConfiguration('params_file'),
                        {'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool)}],
            output='screen',
            emulate_tty=True,
        ),
    ])
