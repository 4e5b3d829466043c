"""Regenerate config/default.yaml, and make the parameter reference page, from the schema.

Usage: .venv/bin/python tools/gen_param_docs.py   (tests/workspace checks default.yaml is
current). The docs build (docs/conf.py) writes docs/reference/parameters.md with
:func:`parameters_page` at every build, so the page is never stale.
"""

from pathlib import Path

from seft_msgs_py import parameters as P

ROOT = Path(__file__).resolve().parents[1]
SHORT = {'ground_motion_publisher': 'gm', 'reference_force_builder': 'rfb',
         'force_servo_controller': 'ctrl', 'rig': 'rig', 'recorder': 'rec'}


def _yaml(v) -> str:
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, float):
        r = repr(v)
        return r.replace('e', '.0e') if 'e' in r and '.' not in r.split('e')[0] else r
    if isinstance(v, str):
        return f"'{v}'"
    return str(v)


def default_yaml() -> str:
    lines = ['# seft: every parameter of an experiment with its default (ROS 2 --params-file '
             'format).', '# Generated from seft_msgs_py/parameters.py by tools/gen_param_docs.py.',
             '# Start a node by hand with it: <node> --ros-args --params-file '
             'config/default.yaml', '# or run an experiment: .venv/bin/seft run '
             'config/default.yaml', '/**:', '  ros__parameters:']
    for s in P.SCHEMA:
        if s.name == 'bag_path':
            continue
        unit = f' [{s.unit}]' if s.unit else ''
        lines.append(f'    # {s.description}{unit} Expected: {s.expected()}.')
        lines.append(f'    {s.name}: {_yaml(s.default)}')
    lines.append('    use_sim_time: true')
    return '\n'.join(lines) + '\n'


def readme_table() -> str:
    rows = ['| parameter | default | unit | allowed | nodes | meaning |',
            '|---|---|---|---|---|---|']
    for s in P.SCHEMA:
        nodes = [SHORT[n] for n in s.nodes if n != 'recorder'] or ['rec']
        nodes = 'all' if set(s.nodes) == set(P.NODES) else ', '.join(nodes)
        desc = s.description.replace('|', '\\|')
        rows.append(f'| `{s.name}` | `{s.default!r}` | {s.unit or "-"} | {s.expected()} | '
                    f'{nodes} | {desc} |')
    return '\n'.join(rows)


PAGE_HEAD = """# Parameters

Every parameter is declared by the nodes that use it, with a `ParameterDescriptor` giving the
description, unit and range. Values are checked at start-up, and run-time changes go through
a validation callback. One schema holds them all: `seft_msgs_py/parameters.py`.
`config/default.yaml` lists every one of them with its default, in `--params-file` format.
On the command line (`--set NAME=VALUE`) a value is read by its type here: `1e-12` is a
float, `true`/`false` a bool, text stays text.

Node abbreviations used below: gm = ground_motion_publisher, rfb = reference_force_builder,
ctrl = force_servo_controller, rec = recorder; the recorder stores all parameters. This page
and `config/default.yaml` are generated from the schema (`tools/gen_param_docs.py`, at every
docs build).

"""


def parameters_page() -> str:
    """The parameter reference page (Markdown) of the docs."""
    return PAGE_HEAD + readme_table() + '\n'


def main() -> None:
    (ROOT / 'config' / 'default.yaml').write_text(default_yaml())


if __name__ == '__main__':
    main()
