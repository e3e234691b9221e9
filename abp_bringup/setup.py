from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'abp_bringup'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml') + glob('config/*.xml')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='abp maintainers',
    maintainer_email='abp-maintainers@example.com',
    description=(
        'Whole-graph parameters, launch file, Recognize client '
        'and rosbag2 record/replay for abp.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'recognize = abp_bringup.recognize_client:main',
            'bag_recorder = abp_bringup.bag_recorder_node:main',
            'bag_player = abp_bringup.bag_player:main',
            'health = abp_bringup.health:main',
            'lifecycle_manager = abp_bringup.lifecycle_manager:main',
            'graph_container = abp_bringup.graph_container:main',
        ],
    },
)
