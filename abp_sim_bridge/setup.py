from setuptools import find_packages, setup

PACKAGE = 'abp_sim_bridge'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', ['config/fastdds_large_images.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='abp maintainers',
    maintainer_email='abp-maintainers@example.com',
    description=(
        'Simulated uBot-6 and ARcube world behind the '
        "robot's own topics: rendering, integration, contact physics."
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'sim_bridge = abp_sim_bridge.sim_bridge_node:main',
            'scripted_operator = abp_sim_bridge.scripted_operator_node:main',
        ],
    },
)
