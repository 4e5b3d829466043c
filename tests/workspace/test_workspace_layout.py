"""The colcon workspace builds with colcon from PyPI and installs startable executables."""

import os
from pathlib import Path
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from seft_msgs_py import parameters
from seft_msgs_py.topics import TOPICS

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ('seft_msgs_py', 'seft_plant_sim', 'seft_ros')
EXECUTABLES = {
    'seft_plant_sim': ('rig',),
    'seft_ros': ('ground_motion_publisher', 'reference_force_builder', 'force_servo_controller',
                 'recorder', 'loop', 'seft'),
}


@pytest.mark.parametrize('pkg', PACKAGES)
def test_package_layout(pkg):
    src = ROOT / 'src' / pkg
    root = ET.parse(src / 'package.xml').getroot()
    assert root.get('format') == '3'
    assert root.findtext('name') == pkg
    assert root.find('export').findtext('build_type') == 'ament_python'
    assert (src / 'resource' / pkg).is_file()
    assert f'install_scripts=$base/lib/{pkg}' in (src / 'setup.cfg').read_text()


@pytest.fixture(scope='module')
def colcon_install(tmp_path_factory):
    base = tmp_path_factory.mktemp('ws')
    colcon = Path(sys.executable).parent / 'colcon'
    proc = subprocess.run(
        [str(colcon), '--log-base', str(base / 'log'), 'build', '--base-paths', str(ROOT / 'src'),
         '--build-base', str(base / 'build'), '--install-base', str(base / 'install')],
        cwd=base, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return base / 'install'


def test_colcon_build_installs_every_executable(colcon_install):
    for pkg, exes in EXECUTABLES.items():
        for exe in exes:
            path = colcon_install / pkg / 'lib' / pkg / exe
            assert path.is_file() and os.access(path, os.X_OK), path
        index = colcon_install / pkg / 'share' / 'ament_index' / 'resource_index' / 'packages'
        assert (index / pkg).is_file()


def test_installed_node_starts_and_rejects_bad_parameter(colcon_install, ros_env):
    """`ros2 run seft_plant_sim rig` equivalent: the installed executable runs its main()."""
    env = ros_env                   # the session's claimed domain (conftest.claim_domain)
    cmd = ['sh', '-c', f'. {colcon_install}/setup.sh && '
           f'{colcon_install}/seft_plant_sim/lib/seft_plant_sim/rig --ros-args -p dt:=-1.0']
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip() == 'rig: error: parameter dt=-1.0: expected float > 1e-05 <= 1'
    # a flow-control window below the recorder's acknowledgement interval would stall the run
    cmd[-1] = cmd[-1].replace('dt:=-1.0', 'recorder_window_steps:=20')
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        'rig: error: parameter recorder_window_steps=20: expected 0 or >= 100 (the recorder '
        'acknowledges every 50 steps and receives the samples in batches of 10)')


def test_docs_document_every_parameter_and_topic():
    sys.path.insert(0, str(ROOT / 'tools'))
    import gen_param_docs
    page = gen_param_docs.parameters_page()      # docs/reference/parameters.md, every build
    for spec in parameters.SCHEMA:
        assert f'| `{spec.name}` |' in page, spec.name
    graph = (ROOT / 'docs' / 'design' / 'node-graph.md').read_text()
    for topic in TOPICS:
        assert f'| `{topic.name}` | `{topic.type_name}` |' in graph, topic.name


def test_readme_is_the_front_door():
    """What seft is, the two commands, one result, where next: at most about 250 lines."""
    readme = (ROOT / 'README.md').read_text()
    assert len(readme.splitlines()) <= 250
    assert 'bash tools/test.sh' in readme and 'bash tools/main.sh' in readme
    assert 'tools/test.sh' in (ROOT / '.ci' / 'run').read_text()
    assert 'bash tools/docs.sh' in (ROOT / 'tools' / 'test.sh').read_text()
    for link in ('docs/index.md', 'docs/results/main-job.md', 'docs/figures/main_job.png'):
        assert link in readme and (ROOT / link).is_file(), link


def test_generated_parameter_docs_are_current():
    sys.path.insert(0, str(ROOT / 'tools'))
    import gen_param_docs
    assert (ROOT / 'config' / 'default.yaml').read_text() == gen_param_docs.default_yaml(), \
        'run tools/gen_param_docs.py'


def test_default_config_lists_every_parameter_with_its_default():
    from seft_ros.cli.config import load_config
    values = load_config(ROOT / 'config' / 'default.yaml')
    expected = {s.name: s.default for s in parameters.SCHEMA if s.name != 'bag_path'}
    assert values == expected


_NO_PLANT_SIM = """
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == 'seft_plant_sim' or name.startswith('seft_plant_sim.'):
            raise ImportError('blocked: ' + name)
sys.meta_path.insert(0, Block())
import seft_ros.nodes.ground_motion_publisher, seft_ros.nodes.reference_force_builder
import seft_ros.nodes.force_servo_controller, seft_ros.nodes.recorder
from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_ros.core.reference_force import ReferenceForceBuilder
p = parameters.resolve({'rig_model': 'delay', 'predictor': 'model', 'alpha': 1.0})
ReferenceForceBuilder.from_parameters(p)
try:
    ReferenceForceBuilder.from_parameters(parameters.resolve({'predictor': 'model', 'alpha': 1.0}))
except ParameterError as exc:
    print('refused:', exc)
"""


def test_controller_side_runs_without_the_plant_simulation():
    """A lab's controller host installs no plant simulation (issue: structure): the nodes of
    the computational side import, and a delay-rig `model` builder is built, with
    seft_plant_sim made unimportable; the servohydraulic `model` says what it misses."""
    proc = subprocess.run([sys.executable, '-c', _NO_PLANT_SIM], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert 'refused: the force loop of rig_model servohydraulic' in proc.stdout
    assert 'seft_plant_sim' in proc.stdout
