from setuptools import find_packages, setup

PACKAGE = 'abp_skills'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='abp maintainers',
    maintainer_email='abp-maintainers@example.com',
    description=(
        'ORBIT, PUSH, LIFT and FLIP action '
        'servers with Pinocchio kinematics and Ruckig trajectories.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'skill_servers = abp_skills.skills_node:main',
            'orbit_server = abp_skills.skills_node:orbit_main',
            'push_server = abp_skills.skills_node:push_main',
            'lift_server = abp_skills.skills_node:lift_main',
            'flip_server = abp_skills.skills_node:flip_main',
            'operator_skills = abp_skills.operator_node:main',
        ],
    },
)
