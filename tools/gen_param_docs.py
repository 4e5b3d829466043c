"""Regenerate config/default.yaml and the README parameter table from the parameter schema.

Usage: .venv/bin/python tools/gen_param_docs.py   (tests/workspace checks both are current)
"""

from pathlib import Path

from seft_msgs_py import parameters as P

ROOT = Path(__file__).resolve().parents[1]
BEGIN, END = '<!-- parameters:begin -->', '<!-- parameters:end -->'
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


def readme_with_table(text: str) -> str:
    i, j = text.index(BEGIN) + len(BEGIN), text.index(END)
    return text[:i] + '\n' + readme_table() + '\n' + text[j:]


def main() -> None:
    (ROOT / 'config' / 'default.yaml').write_text(default_yaml())
    readme = ROOT / 'README.md'
    readme.write_text(readme_with_table(readme.read_text()))


if __name__ == '__main__':
    main()
