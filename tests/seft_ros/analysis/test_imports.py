"""The modules of ``seft_ros.analysis`` import each other without a cycle (issue 31).

Each module's imports are read from its source with ``ast`` (every ``import`` and
``from ... import`` statement, at the top or inside a function: a lazy import is a cycle
all the same, it only fails later), resolved to the package's modules, and the graph is
searched for a cycle. The search is tested on a package written here with one.
"""

import ast
from pathlib import Path

import seft_ros.analysis

PACKAGE = 'seft_ros.analysis'


def imported_modules(path: Path, package: str, modules: set[str]) -> set[str]:
    """The modules of `modules` (``'<package>.<name>'``) that the source at `path` imports."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:                       # relative: from the package, or above it
                parent = package.rsplit('.', node.level - 1)[0] if node.level > 1 else package
                base = f'{parent}.{base}' if base else parent
            # 'from seft_ros.analysis import bag' imports the module bag
            names = [base] + [f'{base}.{alias.name}' for alias in node.names]
        else:
            continue
        for name in names:
            while name:
                if name in modules:
                    found.add(name)
                    break
                name = name.rpartition('.')[0]
    return found


def import_graph(directory: Path, package: str) -> dict[str, set[str]]:
    """``{module: the package's modules it imports}`` of every module of `directory`."""
    files = {f'{package}.{p.stem}': p for p in sorted(directory.glob('*.py'))
             if p.stem != '__init__'}
    return {name: imported_modules(path, package, set(files)) - {name}
            for name, path in files.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of `graph` as ``[a, b, ..., a]``, or None (depth-first search)."""
    state: dict[str, int] = {}           # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node):
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state:
                cycle = visit(nxt)
                if cycle:
                    return cycle
        state[node] = 2
        path.pop()
        return None

    for node in sorted(graph):
        if node not in state:
            cycle = visit(node)
            if cycle:
                return cycle
    return None


def test_analysis_has_no_import_cycle():
    directory = Path(seft_ros.analysis.__file__).parent
    graph = import_graph(directory, PACKAGE)
    assert {f'{PACKAGE}.bag', f'{PACKAGE}.metrics', f'{PACKAGE}.report'} <= set(graph)
    assert f'{PACKAGE}.reference' in graph[f'{PACKAGE}.metrics']         # edges are found
    cycle = find_cycle(graph)
    assert cycle is None, 'import cycle: ' + ' -> '.join(cycle)


def test_analysis_has_no_structure_twin_of_a_module():
    """Every test is a structure: no module is the structure twin of another (issue 31)."""
    stems = {p.stem for p in Path(seft_ros.analysis.__file__).parent.glob('*.py')}
    twins = sorted(s for s in stems if s.startswith('structure_') and
                   s[len('structure_'):] in stems)
    assert not twins, twins


def test_a_lazy_import_cycle_is_found(tmp_path):
    """The check itself: a cycle through an import inside a function, a relative import
    and a 'from package import module' are all found; a package without one passes."""
    pkg = tmp_path / 'pkg'
    pkg.mkdir()
    (pkg / '__init__.py').write_text('')
    (pkg / 'a.py').write_text('import os\nfrom pkg.b import thing\n')
    (pkg / 'b.py').write_text('def thing():\n    from . import c\n    return c\n')
    (pkg / 'c.py').write_text('import json\n')
    graph = import_graph(pkg, 'pkg')
    assert graph == {'pkg.a': {'pkg.b'}, 'pkg.b': {'pkg.c'}, 'pkg.c': set()}
    assert find_cycle(graph) is None
    (pkg / 'c.py').write_text('def late():\n    from pkg import a\n    return a\n')
    cycle = find_cycle(import_graph(pkg, 'pkg'))
    assert cycle == ['pkg.a', 'pkg.b', 'pkg.c', 'pkg.a']
