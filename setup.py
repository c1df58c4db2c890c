from glob import glob

from setuptools import find_packages, setup


PACKAGE = 'curve_formation'

# One console script per node, named for what it does, plus the command-line tool.
NODES = {
    'curve_server': 'curve_formation.nodes.curve_server:main',
    'formation_controller': 'curve_formation.nodes.formation_controller:main',
    'fake_robot': 'curve_formation.nodes.fake_robot:main',
    'fake_arena': 'curve_formation.nodes.fake_arena:main',
    'robot_bridge': 'curve_formation.nodes.robot_bridge:main',
    'formation_recorder': 'curve_formation.nodes.recorder:main',
    'camera_tracker': 'curve_formation.nodes.camera_tracker:main',
    'fake_camera': 'curve_formation.nodes.fake_camera:main',
    'node_group': 'curve_formation.nodes.node_group:main',
}

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'benchmarks']),
    package_data={PACKAGE: ['fastdds_large_data.xml', 'fastdds_udp.xml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml', 'LICENSE']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml') + glob('config/*.json')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
    ],
    # What `sim`, `run --bag`, `analyze` and the nodes need at run time (requirements.txt
    # pins the ROS 2 wheels and the test tools; package.xml names the same with rosdep keys).
    install_requires=['setuptools', 'numpy', 'scipy', 'numba', 'matplotlib', 'PyYAML',
                      'pydantic>=2', 'opencv-python-headless', 'rosbags>=0.11', 'mcap>=1.2',
                      'pyserial', 'mujoco', 'imageio-ffmpeg', 'pillow'],
    zip_safe=True,
    maintainer='curve_formation maintainers',
    maintainer_email='curve-formation@example.org',
    description='Formation control of nonholonomic robots along parametric curves.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [f'{name} = {target}' for name, target in NODES.items()]
        + ['curve-formation = curve_formation.cli:main'],
    },
)
