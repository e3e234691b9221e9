from setuptools import find_packages, setup

PACKAGE = 'abp_belief'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        # The robot set's ATGs learned from the MuJoCo outcome survey (docs/BENCHMARKS.md).
        ('share/' + PACKAGE + '/models', ['models/learned_robot_mujoco.npz',
                                          'models/learned_robot_mujoco_70trials.npz',
                                          'models/learned_robot_from_bags.npz']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='abp maintainers',
    maintainer_email='abp-maintainers@example.com',
    description=(
        'ARcube model populations, Aspect Transition Graphs, observation '
        'model and the Bayes filter (paper III-A..C).'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'belief = abp_belief.belief_node:main',
            'models = abp_belief.models_cli:main',
            'learn_atg = abp_belief.learn_atg_cli:main',
        ],
    },
)
