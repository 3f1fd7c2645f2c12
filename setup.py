"""ament_python package; also a plain pip package (see README for both install paths)."""
from glob import glob

from setuptools import find_packages, setup

package_name = 'planar_vo'

# The ROS 2 Jazzy wheels and the libraries that a ROS install gets from apt instead.
WHEELS = [
    'ros-jazzy-rclpy',
    'ros-jazzy-common-interfaces',
    'ros-jazzy-rmw-fastrtps-cpp',
    'ros-jazzy-ament-index-python',
    'opencv-python-headless',
    'numpy',
    'pyyaml',
    'rosbags',
    'tqdm',
]

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
        # The bundled bag: planar_vo_demo and planar_vo_bench play it when given no bag.
        ('share/' + package_name + '/bags/default', glob('bags/default/*')),
    ],
    # Runtime dependencies come from package.xml (colcon/rosdep) or the 'wheels' extra (pip),
    # never from install_requires: apt's python3-opencv has no pip metadata.
    install_requires=['setuptools'],
    extras_require={
        'wheels': WHEELS,
        'test': ['pytest', 'hypothesis', 'ruff', 'matplotlib', 'colcon-common-extensions',
                 'setuptools<80'],
    },
    zip_safe=True,
    maintainer='planar_vo maintainers',
    maintainer_email='planar-vo@example.com',
    description='Planar monocular visual odometry with 1-point RANSAC on the ground homography',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'planar_vo_paper_experiment = planar_vo.tools.experiments.paper_experiment:main',
            'planar_vo_node = planar_vo.ros.node:main',
            'planar_vo_replay = planar_vo.tools.replay:main',
            'planar_vo_demo = planar_vo.tools.demo:main',
            'planar_vo_bench = planar_vo.tools.benchmark:main',
            'planar_vo_soak = planar_vo.tools.soak:main',
            'planar_vo_synth = planar_vo.synth:main',
            'planar_vo_calibrate = planar_vo.tools.calibrate:main',
            'planar_vo_mounting_experiment = planar_vo.tools.experiments.mounting_experiment:main',
        ],
    },
)
