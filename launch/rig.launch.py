"""Launch the steering rig: the valves and the cylinder of a rig YAML as one node (a real ROS 2
install; launch is not on PyPI).

    ros2 launch pcv_sim rig.launch.py                                   # shipped config/rig.yaml, lockstep
    ros2 launch pcv_sim rig.launch.py rig_config:=/path/to/my_rig.yaml control_period:=0.01
    ros2 launch pcv_sim rig.launch.py time_mode:=real                   # hardware in the loop
    ros2 launch pcv_sim rig.launch.py time_mode:=real use_sim_time:=true   # follow a simulation's /clock
    ros2 launch pcv_sim rig.launch.py record:=true record_directory:=bags  # record a bag until Ctrl-C
"""
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='', description='namespace of the rig (topics are relative)'),
        DeclareLaunchArgument('rig_config', default_value='',
                              description="rig YAML (valves, cylinder, timing); '' = the shipped config/rig.yaml"),
        DeclareLaunchArgument('time_mode', default_value='simulated',
                              description='simulated (one /clock, lockstep with the controller) or real'),
        DeclareLaunchArgument('lockstep', default_value='true',
                              description='simulated time: wait for every valve\'s command each control period'),
        DeclareLaunchArgument('control_period', default_value='0.0',
                              description="s; 0 = the rig YAML's rig.control_period"),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='with time_mode real: the model follows /clock (e.g. Gazebo)'),
        DeclareLaunchArgument('record', default_value='false',
                              description='record every valve, the cylinder, faults and events to a bag'),
        DeclareLaunchArgument('record_directory', default_value='.', description='where the bag is created'),
        Node(
            package='pcv_sim',
            executable='rig',
            name='rig',
            namespace=LaunchConfiguration('namespace'),
            parameters=[{
                'rig_config': LaunchConfiguration('rig_config'),
                'time_mode': LaunchConfiguration('time_mode'),
                'lockstep': ParameterValue(LaunchConfiguration('lockstep'), value_type=bool),
                'control_period': ParameterValue(LaunchConfiguration('control_period'), value_type=float),
                'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool),
                'record.enabled': ParameterValue(LaunchConfiguration('record'), value_type=bool),
                'record.directory': LaunchConfiguration('record_directory'),
            }],
            output='screen',
            emulate_tty=True,
        ),
    ])
