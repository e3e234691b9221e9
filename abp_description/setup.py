from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'abp_description'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/urdf', glob('urdf/*.urdf')),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/profiles', glob('profiles/*.yaml') + glob('profiles/*.npz')),
        ('share/' + PACKAGE + '/rviz', glob('rviz/*.rviz')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='abp maintainers',
    maintainer_email='abp-maintainers@example.com',
    description=(
        'URDF and camera intrinsics of the '
        'uBot-6-like robot, with a Pinocchio kinematics helper and the robot_state '
        'node that publishes its tf tree.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'robot_state = abp_description.robot_state_node:main',
        ],
    },
)
