"""Install knode_swarm_ros as an ament_python package (colcon) or with pip.

colcon puts the executables under ``lib/knode_swarm_ros`` (see setup.cfg) so that
``ros2 run knode_swarm_ros <exe>`` finds them; pip in a virtual environment puts them
in the environment's ``bin``. Both install the data files below under the prefix's
``share``, so ``ament_index_python`` finds the package when AMENT_PREFIX_PATH holds
that prefix.

Only numpy and pyyaml are install_requires: rclpy and the message packages come from
ROS 2 (apt/colcon) or from the ros-jazzy-* wheels, and torch must be pinned to an
exact CPU build; requirements.txt pins all of them for a virtual environment. A robot
that runs only the ONNX twins needs the ``robot`` extra (onnxruntime) and no torch
(requirements-robot.txt pins that set).
"""

import os

from setuptools import find_packages, setup

PACKAGE_NAME = 'knode_swarm_ros'
HERE = os.path.dirname(os.path.abspath(__file__))


def _config_data_files():
    """Every file under config/, keeping sub-folders, as (share dir, [files])."""
    entries = []
    root = os.path.join(HERE, 'config')
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith(('.', '__')))
        files = sorted(
            os.path.relpath(os.path.join(dirpath, f), HERE)
            for f in filenames
            if not f.startswith('.') and not f.endswith(('~', '.pyc'))
        )
        if files:
            rel = os.path.relpath(dirpath, HERE)
            entries.append((os.path.join('share', PACKAGE_NAME, rel), files))
    return entries


setup(
    name=PACKAGE_NAME,
    version='0.1.0',
    description='Learn decentralised swarm controllers with KNODE and deploy them in ROS 2.',
    license='MIT',
    maintainer='knode_swarm_ros maintainers',
    maintainer_email='maintainers@knode-swarm.dev',
    python_requires='>=3.10',
    packages=find_packages(exclude=['tests', 'tests.*', 'training', 'training.*', 'bench', 'bench.*']),
    # Shipped, pretrained policies and scenario files (found at run time through importlib.resources)
    # and the monitor's page.
    package_data={
        PACKAGE_NAME: ['policies/*.pt', 'policies/*.onnx', 'scenarios/*.yaml', 'nodes/monitor/page.html']
    },
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE_NAME]),
        ('share/' + PACKAGE_NAME, ['package.xml']),
    ]
    + _config_data_files(),
    install_requires=['numpy', 'pyyaml'],
    # bag: reading and writing bags (knode_swarm_ros.bag: rosbags is pure Python, no ROS needed);
    # robot: the torch-free runtime (onnxruntime); torch: the TorchScript runtime and training;
    # sweep: training.sweep's cells on a local Ray or a cluster (one worker needs no Ray).
    extras_require={
        'test': ['pytest'],
        'bag': ['rosbags==0.11.9'],
        'robot': ['onnxruntime==1.32.0'],
        'torch': ['torch==2.13.0'],
        'sweep': ['ray==2.60.0'],
        'monitor': ['aiohttp==3.14.5'],
    },
    zip_safe=False,
    entry_points={
        'console_scripts': [
            'agent = knode_swarm_ros.nodes.agent:main',
            'agents = knode_swarm_ros.nodes.agents:main',
            'simulator = knode_swarm_ros.nodes.simulator:main',
            'recorder = knode_swarm_ros.nodes.recorder:main',
            'swarm = knode_swarm_ros.nodes.swarm:main',
            'monitor = knode_swarm_ros.nodes.monitor:main',
        ],
    },
)
