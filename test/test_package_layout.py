"""The package's layout holds: no import circles between its modules, every package names its
public API in ``__all__``, and no source file points its reader at something the repository
does not hold (a tracker's issue number, a document kept elsewhere).

Everything here reads the sources with :mod:`ast` and regular expressions: nothing is imported,
so a cycle is found even where Python would tolerate it until the day a name moves."""
from __future__ import annotations

import ast
import pathlib
import re
from typing import Dict, Iterator, List, Optional, Set, Tuple

ROOT = pathlib.Path(__file__).resolve().parent.parent
PACKAGE = ROOT / 'seaforce_ros'


# --- the import graph ------------------------------------------------------------------------

def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix('').parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def _modules() -> Dict[str, pathlib.Path]:
    return {_module_name(p): p for p in sorted(PACKAGE.rglob('*.py'))
            if '__pycache__' not in p.parts}


def _is_type_checking(test: ast.expr) -> bool:
    return ((isinstance(test, ast.Name) and test.id == 'TYPE_CHECKING')
            or (isinstance(test, ast.Attribute) and test.attr == 'TYPE_CHECKING'))


def _import_time_nodes(body: List[ast.stmt]) -> Iterator[ast.stmt]:
    """The import statements that run when the module is imported: module level, class bodies,
    ``if``/``try``/``with`` blocks; not function bodies, not ``if TYPE_CHECKING:``."""
    for node in body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        elif isinstance(node, ast.If):
            if not _is_type_checking(node.test):
                yield from _import_time_nodes(node.body)
            yield from _import_time_nodes(node.orelse)
        elif isinstance(node, ast.Try):
            for block in (node.body, node.orelse, node.finalbody):
                yield from _import_time_nodes(block)
            for handler in node.handlers:
                yield from _import_time_nodes(handler.body)
        elif isinstance(node, (ast.ClassDef, ast.With)):
            yield from _import_time_nodes(node.body)


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ''
    base = module.split('.') if is_package else module.split('.')[:-1]
    base = base[:len(base) - (node.level - 1)]
    return '.'.join(base + ([node.module] if node.module else []))


def import_graph() -> Dict[str, Set[str]]:
    """module -> the package's modules it imports at import time. ``from pkg import name``
    points at ``pkg.name`` when that is a module, else at ``pkg`` (its ``__init__``)."""
    modules = _modules()
    graph: Dict[str, Set[str]] = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        is_package = path.name == '__init__.py'
        targets: Set[str] = set()
        for node in _import_time_nodes(tree.body):
            if isinstance(node, ast.Import):
                targets.update(alias.name for alias in node.names)
            else:
                source = _resolve(name, is_package, node)
                for alias in node.names:
                    sub = f'{source}.{alias.name}'
                    targets.add(sub if sub in modules else source)
        graph[name] = {t for t in targets if t in modules and t != name}
    return graph


def find_cycles(graph: Dict[str, Set[str]]) -> List[List[str]]:
    """One cycle (a list of modules, the first repeated at the end) per strongly connected
    component of more than one module (Tarjan's algorithm, iterative)."""
    index: Dict[str, int] = {}
    low: Dict[str, int] = {}
    on_stack: Set[str] = set()
    stack: List[str] = []
    components: List[List[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work: List[Tuple[str, Iterator[str]]] = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child: Optional[str] = next(children, None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        components.append(sorted(component))
            elif child not in index:
                index[child] = low[child] = counter
                counter += 1
                stack.append(child)
                on_stack.add(child)
                work.append((child, iter(sorted(graph[child]))))
            elif child in on_stack:
                low[node] = min(low[node], index[child])
    return [_cycle_in(graph, set(c)) for c in components]


def _cycle_in(graph: Dict[str, Set[str]], component: Set[str]) -> List[str]:
    """A shortest cycle through the component's first module (breadth-first)."""
    start = min(component)
    previous: Dict[str, str] = {}
    frontier = [start]
    while frontier:
        following = []
        for node in frontier:
            for child in sorted(graph[node] & component):
                if child == start:
                    path = [node]
                    while path[-1] != start:
                        path.append(previous[path[-1]])
                    return [start] + path[::-1][1:] + [start]
                if child not in previous:
                    previous[child] = node
                    following.append(child)
        frontier = following
    return sorted(component)


def test_the_graph_sees_the_package():
    graph = import_graph()
    assert 'seaforce_ros.core.controller' in graph['seaforce_ros.core']
    assert 'seaforce_ros.core.params' in graph['seaforce_ros.core.controller']
    assert len(graph) > 60


def test_find_cycles_names_the_circle():
    graph = {'a': {'b'}, 'b': {'c'}, 'c': {'a', 'd'}, 'd': set(), 'e': {'d'}}
    assert find_cycles(graph) == [['a', 'b', 'c', 'a']]
    assert find_cycles({'a': {'b'}, 'b': set()}) == []


def test_no_import_cycles():
    cycles = find_cycles(import_graph())
    assert not cycles, 'import cycles: ' + '; '.join(' -> '.join(c) for c in cycles)


# --- __all__ ---------------------------------------------------------------------------------

def _bound_names(tree: ast.Module) -> Set[str]:
    names: Set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split('.')[0] for a in node.names)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, ast.Name))
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    return names


def _declared_all(tree: ast.Module) -> Optional[List[str]]:
    for node in tree.body:
        if (isinstance(node, ast.Assign)
                and any(isinstance(t, ast.Name) and t.id == '__all__' for t in node.targets)):
            return list(ast.literal_eval(node.value))
    return None


def test_every_package_lists_its_public_api():
    """Each ``__init__.py`` declares ``__all__``; each entry is a name the ``__init__`` binds
    or one of the package's own modules or subpackages, and appears once."""
    problems = []
    for init in sorted(PACKAGE.rglob('__init__.py')):
        tree = ast.parse(init.read_text(), str(init))
        declared = _declared_all(tree)
        where = init.relative_to(ROOT)
        if declared is None:
            problems.append(f'{where}: no __all__')
            continue
        if len(set(declared)) != len(declared):
            problems.append(f'{where}: __all__ lists a name twice')
        bound = _bound_names(tree)
        for name in declared:
            if not (name in bound or (init.parent / f'{name}.py').exists()
                    or (init.parent / name / '__init__.py').exists()):
                problems.append(f'{where}: __all__ names {name!r}, which it neither binds '
                                'nor holds as a module')
    assert not problems, '\n'.join(problems)


# --- references to what is not in the repository ---------------------------------------------

#: The source trees whose comments, docstrings and notes are checked, and single files.
CHECKED = ('seaforce_ros', 'bench', 'test', 'scripts', 'launch', 'config', 'msg_defs',
           'setup.py', 'setup.cfg', 'package.xml', '.ci')
SUFFIXES = {'.py', '.xml', '.yaml', '.yml', '.cfg', '.txt', '.md', '.msg', '.action', '.srv',
            '.sh', '.json', ''}
SKIP_PARTS = {'__pycache__', 'build', 'install', 'log', '.venv'}

#: A tracker's issue by number ("issue" + number, "#" + number) or by the bare word as a
#: document ("the issue's case"); a path into a directory beside the repository.
TRACKER = re.compile(r"(?i)\bissues?\s*(?:#|no\.?\s*)?\d+|(?<![\w/&#'\"])#\d{1,5}\b"
                     r"|\b(?:the|this|that|an?) issue(?:'s)?\b|\bissue\s*[\"\u201c]")
OUTSIDE = re.compile(r'\.\./shared\b|/work/shared\b')
MARKDOWN = re.compile(r'[\w./-]*\w\.md\b')


def _checked_files() -> Iterator[pathlib.Path]:
    this = pathlib.Path(__file__).resolve()
    for entry in CHECKED:
        path = ROOT / entry
        paths = [path] if path.is_file() else sorted(path.rglob('*')) if path.is_dir() else []
        for p in paths:
            if (p.is_file() and p.suffix in SUFFIXES and p.resolve() != this
                    and not SKIP_PARTS & set(p.relative_to(ROOT).parts)):
                yield p


def _markdown_exists(reference: str, source: pathlib.Path, names: Set[str]) -> bool:
    if '/' not in reference:
        return reference in names
    bases = [source.parent] + [b for b in source.parent.parents if ROOT in b.parents or b == ROOT]
    # a path that leaves the repository (../shared/...) is outside it even where it exists
    for base in bases:
        target = (base / reference).resolve()
        if target.exists() and (target == ROOT or ROOT in target.parents):
            return True
    return False


def test_no_reference_outside_the_repository():
    """No file refers to an issue tracker's entry or to a document the repository does not hold:
    a comment says what and why itself, or names a file that is here."""
    files = list(_checked_files())
    names = {p.name for p in ROOT.rglob('*.md') if not SKIP_PARTS & set(p.parts)}
    problems = []
    for path in files:
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        for number, line in enumerate(text.splitlines(), 1):
            found = [m.group(0) for m in TRACKER.finditer(line)]
            found += [m.group(0) for m in OUTSIDE.finditer(line)]
            found += [m.group(0) for m in MARKDOWN.finditer(line)
                      if not _markdown_exists(m.group(0), path, names)]
            if found:
                problems.append(f'{path.relative_to(ROOT)}:{number}: {", ".join(found)}')
    assert len(files) > 150
    assert not problems, 'references to what is not in the repository:\n' + '\n'.join(problems)


def test_the_reference_check_catches_what_it_should():
    bad = ['see issue 12', 'fixed in issue #13', '(Issue 11)', 'as in #7', "the issue's drift",
           'issue "The cycle"']
    assert all(TRACKER.search(line) for line in bad)
    good = ['issues a command', 'ros2 launch ... # 3 s', "color '#222'", 'x.issue_time']
    assert not any(TRACKER.search(line) for line in good)
    assert OUTSIDE.search('from ../shared/notes') and not OUTSIDE.search('../sharedness')
    names = {'README.md'}
    assert _markdown_exists('README.md', ROOT / 'x.py', names)
    assert not _markdown_exists('DESIGN.md', ROOT / 'x.py', names)
    assert _markdown_exists('docs/parameters.md', ROOT / 'x.py', names)
    assert _markdown_exists('core/README.md', PACKAGE / 'core' / 'params.py', names)
    assert not _markdown_exists('../shared/DESIGN.md', PACKAGE / 'core' / 'params.py', names)
