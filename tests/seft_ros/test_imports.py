"""The modules of ``seft_ros`` import each other without the cycles we removed: none within
``seft_ros.analysis`` (issue 31), none through ``seft_ros.opensees``, and ``seft_ros.core``
imports no plug-in (issue 40: OpenSees is an adapter the core loads by name,
:mod:`seft_ros.core.models`).

Each module's imports are read from its source with ``ast`` (every ``import`` and
``from ... import`` statement, at the top or inside a function: a lazy import is a cycle
all the same, it only fails later), resolved to the package's modules, and the graph is
searched for a cycle. The search is tested on a package written here with one.
"""

import ast
from pathlib import Path

import seft_ros
import seft_ros.analysis
from seft_ros.core.models import ComputationalModel, model_kinds, model_plugin

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


def package_graph(root: Path, package: str) -> dict[str, set[str]]:
    """``{module: the modules it imports}`` of every module of the package at `root` and its
    subpackages (names ``'<package>.<sub>.<name>'``)."""
    files = {}
    for path in sorted(root.rglob('*.py')):
        parts = path.relative_to(root).with_suffix('').parts
        if parts[-1] != '__init__':
            files['.'.join((package,) + parts)] = path
    modules = set(files)
    return {name: imported_modules(path, name.rpartition('.')[0], modules) - {name}
            for name, path in files.items()}


def cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of `graph` with more than one module: every
    module on a cycle is in one of them (Tarjan's algorithm, iterative)."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, edges = work[-1]
            nxt = next(edges, None)
            if nxt is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.add(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        out.append(component)
            elif nxt not in index:
                index[nxt] = low[nxt] = len(index)
                stack.append(nxt)
                on_stack.add(nxt)
                work.append((nxt, iter(sorted(graph.get(nxt, ())))))
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
    return out


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


def test_no_import_cycle_involves_opensees_and_core_imports_no_plugin():
    """Issue 40: core/structure <-> opensees/model, core/substructure <-> opensees/part and
    analysis/reference <-> opensees/reference were cycles; the core now loads the plug-in by
    name (an entry point) and imports none of seft_ros.opensees."""
    graph = package_graph(Path(seft_ros.__file__).parent, 'seft_ros')
    assert 'seft_ros.opensees.model' in graph and 'seft_ros.core.structure' in graph
    assert 'seft_ros.core.structure' in graph['seft_ros.opensees.model']     # edges found
    through = [sorted(c) for c in cycles(graph) if any('.opensees.' in m for m in c)]
    assert not through, through
    core = {m: sorted(x for x in deps if x.startswith('seft_ros.opensees'))
            for m, deps in graph.items() if m.startswith('seft_ros.core.')}
    assert not any(core.values()), {m: d for m, d in core.items() if d}


def test_opensees_is_a_plugin_chosen_by_name():
    """The installed entry point gives the OpenSees plug-in by its section key."""
    assert 'opensees' in model_kinds()
    plugin = model_plugin('opensees')
    assert isinstance(plugin, ComputationalModel) and plugin.name == 'opensees'
    for hook in ('reference', 'summary', 'markdown', 'check_runs'):
        assert callable(getattr(plugin, hook))


def test_cycles_finds_every_module_on_a_cycle():
    graph = {'a': {'b'}, 'b': {'c'}, 'c': {'a', 'd'}, 'd': set(), 'e': {'e'}}
    assert cycles(graph) == [{'a', 'b', 'c'}]
    assert cycles({'a': {'b'}, 'b': set()}) == []
