from setuptools import find_packages, setup

PACKAGE = 'abp_planner'

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
        'The Active Belief Planner (paper Alg. 3), '
        'its variants and the Recognize action.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'planner = abp_planner.planner_node:main',
        ],
    },
)
