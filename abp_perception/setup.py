from setuptools import find_packages, setup

PACKAGE = 'abp_perception'

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
    description='ArUco tag detection and generalised-Hough aspect matching (paper Alg. 2).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'artag_detector = abp_perception.artag_detector_node:main',
            'aspect_matcher = abp_perception.aspect_matcher_node:main',
            'calibrate_camera = abp_perception.calibrate_camera_cli:main',
            'camera = abp_perception.camera_node:main',
        ],
    },
)
