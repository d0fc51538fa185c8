"""The documentation holds together: README.md stays a short entry page with a contents list
that links every page of docs/, and every relative link of README.md and docs/*.md reaches a
file of the repository and, where it names one, a heading of that file."""
from __future__ import annotations

import pathlib
import re
from typing import Dict, List, Set

ROOT = pathlib.Path(__file__).resolve().parent.parent
PAGES = [ROOT / 'README.md'] + sorted((ROOT / 'docs').glob('*.md'))

LINK = re.compile(r'\[[^\]]*\]\(([^)\s]+)\)')
HEADING = re.compile(r'^#{1,6}\s+(.*?)\s*#*\s*$')


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r'[^\w\- ]', '', heading.strip().lower())
    return text.replace(' ', '-')


def anchors(path: pathlib.Path) -> Set[str]:
    found: Set[str] = set()
    counts: Dict[str, int] = {}
    in_code = False
    for line in path.read_text().splitlines():
        if line.startswith('```'):
            in_code = not in_code
            continue
        match = None if in_code else HEADING.match(line)
        if match:
            base = slug(match.group(1))
            n = counts.get(base, 0)
            counts[base] = n + 1
            found.add(base if n == 0 else f'{base}-{n}')
    return found


def test_slug_is_githubs():
    assert slug('The demo (`scripts/demo grasp`)') == 'the-demo-scriptsdemo-grasp'
    assert slug('Calibrate, then grasp') == 'calibrate-then-grasp'
    assert slug('Part 1: using it') == 'part-1-using-it'


def test_readme_is_an_entry_page():
    text = (ROOT / 'README.md').read_text()
    assert len(text.splitlines()) <= 250
    assert '## Contents' in text
    for page in sorted((ROOT / 'docs').glob('*.md')):
        assert f'(docs/{page.name})' in text, f'README.md does not link docs/{page.name}'


def test_every_link_reaches_its_target():
    broken: List[str] = []
    for page in PAGES:
        in_code = False
        for number, line in enumerate(page.read_text().splitlines(), 1):
            if line.startswith('```'):
                in_code = not in_code
            if in_code:
                continue
            for target in LINK.findall(line):
                if re.match(r'[a-z]+:', target):
                    continue
                file_part, _, anchor = target.partition('#')
                path = (page.parent / file_part).resolve() if file_part else page
                where = f'{page.relative_to(ROOT)}:{number}: {target}'
                if not path.exists():
                    broken.append(where + ' (no such file)')
                elif anchor and path.suffix == '.md' and anchor not in anchors(path):
                    broken.append(where + ' (no such heading)')
    assert not broken, 'broken links:\n' + '\n'.join(broken)
