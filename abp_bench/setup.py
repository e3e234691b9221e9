from setuptools import find_packages, setup

PACKAGE = 'abp_bench'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    # The real-photo suite's photos and manifest (issue 34), read next to the module.
    package_data={PACKAGE: ['real_photos/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='abp maintainers',
    maintainer_email='abp-maintainers@example.com',
    description='Every abp benchmark and the rendered perception scenes (never needed on a robot).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'bench_filter = abp_bench.filter_benchmark:main',
            'planner_benchmark = abp_bench.planner_benchmark:main',
            'perception_benchmark = abp_bench.perception_benchmark:main',
            'skills_benchmark = abp_bench.skills_benchmark:main',
            'sim_bridge_benchmark = abp_bench.sim_bridge_benchmark:main',
            'render_benchmark = abp_bench.render_benchmark:main',
            'graph_benchmark = abp_bench.graph_benchmark:main',
            'outcome_survey = abp_bench.outcome_survey:main',
            'mujoco_benchmark = abp_bench.mujoco_benchmark:main',
            'atg_learning_curve = abp_bench.atg_learning_curve:main',
            'episode_trace = abp_bench.episode_trace:main',
            'soak = abp_bench.soak:main',
            'transport_benchmark = abp_bench.transport_benchmark:main',
            'make_cubes = abp_bench.make_cubes:main',
            'episode_report = abp_bench.episode_report:main',
        ],
    },
)
