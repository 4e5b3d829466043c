"""Sphinx configuration of the seft documentation (built by tools/docs.sh).

Offline and self-contained: no intersphinx, no remote assets; the pages are Markdown (MyST),
the API reference comes from the numpydoc docstrings, the CLI reference from the argparse
parser, the parameter reference from the one schema (tools/gen_param_docs.py).
"""

import hashlib
import os
from pathlib import Path
import shutil
import subprocess
import sys

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'tools'))
# the node modules import rclpy; ament_index_python wants a prefix path (ENVIRONMENT.md)
os.environ.setdefault('AMENT_PREFIX_PATH', str(ROOT / '.venv'))

import gen_param_docs  # noqa: E402

project = 'seft'
author = 'the seft authors'
copyright = 'the seft authors'

extensions = [
    'myst_parser',
    'sphinx.ext.autodoc',
    'sphinx.ext.autosummary',
    'matplotlib.sphinxext.mathmpl',
    'numpydoc',
    'sphinxarg.ext',
]

source_suffix = {'.rst': 'restructuredtext', '.md': 'markdown'}
exclude_patterns = ['_build', '_generated', 'Thumbs.db', '.DS_Store']
templates_path = ['_templates']
root_doc = 'index'

myst_enable_extensions = ['deflist', 'colon_fence']
myst_heading_anchors = 3

autosummary_generate = True
autodoc_default_options = {'members': True, 'show-inheritance': True}
autodoc_member_order = 'bysource'
autodoc_typehints = 'none'          # the numpydoc Parameters sections carry the types
numpydoc_show_class_members = False
numpydoc_xref_param_type = False
# every cross-reference must resolve (a broken one fails the build under -W); names outside
# seft are not documented here (no intersphinx: the build is offline)
nitpicky = True
nitpick_ignore_regex = [
    (r'py:.*', r'(rclpy|yaml|mcap|threadpoolctl|concurrent|dataclasses|numpy|scipy)(\..*)?'),
    (r'py:.*', r'(exec|repr)'),
]

html_theme = 'furo'
html_title = 'seft'
html_static_path = []
# Equations are rendered at build time by matplotlib's mathtext (``mathmpl``) into images:
# the pages load nothing from the network.
mathmpl_fontsize = 15.0


#: The figures of the docs, each made by the project's own command at build time (into
#: docs/_generated/<name>/, which the pages include): name -> the ``seft`` arguments.
FIGURES = {
    # the reference study's Figure 6: uncompensated, alpha 0 to 1.5 (1.5 goes unstable)
    'main': ['simulate', '--alpha', '0', '0.5', '1', '1.5', '--force', '--name',
             'main job, uncompensated'],
    # adaptive compensation with m, c, k 10 % high at the start, the loop identified from data
    'adaptive': ['simulate', '--alpha', '1', '--rig', 'servohydraulic', '--predictor',
                 'adaptive', '--set', 'adaptive_loop=data', '--set', 'predictor_mass_kg=57.97',
                 '--set', 'predictor_stiffness_N_per_m=232100', '--set',
                 'predictor_damping_N_s_per_m=993.6', '--name', 'adaptive, m c k 10 % high'],
    # the two-pier bridge (docs/structures.md): every DOF, uncompensated (it goes unstable)
    # and with the model-based compensator
    'two_piers': ['simulate', 'config/two_piers.yaml', '--predictor', 'none', 'model',
                  '--force', '--name', 'two piers'],
}


def _sources_hash() -> str:
    """Hash of what the figures depend on: the packages' sources and the commands."""
    h = hashlib.sha256(repr(sorted(FIGURES.items())).encode())
    for path in sorted((ROOT / 'src').rglob('*.py')):
        h.update(path.read_bytes())
    return h.hexdigest()


def _figures(srcdir: Path) -> None:
    """Run each figure's command (both at once), unless its output is current."""
    seft = Path(sys.executable).parent / 'seft'
    stamp_text = _sources_hash()
    procs = []
    for name, args in FIGURES.items():
        out = srcdir / '_generated' / name
        stamp = out / '.stamp'
        if stamp.is_file() and stamp.read_text() == stamp_text:
            continue
        shutil.rmtree(out, ignore_errors=True)
        procs.append((out, stamp, subprocess.Popen(
            [str(seft), *args, '--out', str(out)], cwd=ROOT, stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE, text=True)))
    for out, stamp, proc in procs:
        _, err = proc.communicate(timeout=600)
        if proc.returncode != 0:
            raise RuntimeError(f'docs figure {out.name}: seft failed: {err.strip()[-500:]}')
        stamp.write_text(stamp_text)


def _generate(app):
    """The generated pages and figures: the parameter reference from the schema, the
    figures from the project's commands."""
    srcdir = Path(app.srcdir)
    out = srcdir / 'reference'
    out.mkdir(exist_ok=True)
    text = gen_param_docs.parameters_page()
    page = out / 'parameters.md'
    if not page.exists() or page.read_text() != text:
        page.write_text(text)
    _figures(srcdir)


def setup(app):
    app.connect('builder-inited', _generate)
