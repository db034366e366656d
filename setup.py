"""Install pcv_sim the ament_python way (colcon build) or with pip (pip install -e .)."""
import os
from glob import glob

from setuptools import find_packages, setup

package_name = 'pcv_sim'
here = os.path.dirname(os.path.abspath(__file__))


def _files(pattern):
    """Repo-relative files matching pattern; empty when the directory is absent."""
    return sorted(os.path.relpath(p, here) for p in glob(os.path.join(here, pattern)))


data_files = [
    ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
    ('share/' + package_name, ['package.xml']),
]
for subdir, pattern in (('config', 'config/*.yaml'), ('launch', 'launch/*.launch.py')):
    files = _files(pattern)
    if files:
        data_files.append(('share/' + package_name + '/' + subdir, files))

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=data_files,
    install_requires=[
        'numpy',
        'scipy',
        'pyyaml',
        'mcap',
        'rosbags',
        'matplotlib',
    ],
    # The simulation core compiles with numba when it is installed (`pip install numba`); without
    # it the same functions run as plain Python, correct but ~25x slower (BENCHMARKS.md).
    extras_require={'compiled': ['numba']},
    zip_safe=True,
    maintainer='pcv_sim maintainers',
    maintainer_email='pcv_sim@example.com',
    description='Emulator of a hydraulic proportional pressure control valve as a ROS 2 node.',
    license='MIT',
    python_requires='>=3.10',
    entry_points={
        'console_scripts': [
            'pcv-sim = pcv_sim.cli:main',
            'emulator = pcv_sim.node.emulator:main',
            'demo = pcv_sim.node.demo:main',
            'rig = pcv_sim.node.rig:main',
            'steering_controller = pcv_sim.node.steering_controller:main',
        ],
    },
)
