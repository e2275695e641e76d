"""
Every relative link in README.md and docs/*.md leads somewhere.

The file exists, and a ``#anchor`` names a heading of that file (as GitHub makes heading anchors).
A README that sends a newcomer to a moved or renamed page fails here, not in the newcomer's
browser.
"""
import glob
import os
import re
from typing import List

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..')

_LINK = re.compile(r'(?<!!)\[[^\]]*\]\(([^)\s]+)(?:\s+"[^"]*")?\)')
_REF = re.compile(r'^\s*\[[^\]]+\]:\s*(\S+)', re.M)


def _strip_code(text: str) -> str:
    """Markdown without fenced blocks and inline code (no links live there)."""
    text = re.sub(r'^```.*?^```', '', text, flags=re.S | re.M)
    return re.sub(r'`[^`\n]*`', '', text)


def anchors(text: str) -> set:
    """
    Return the anchors GitHub gives the headings of a page.

    Lower case, punctuation dropped except ``-`` and ``_``, spaces to ``-``, repeats numbered
    ``-1``, ``-2``, ...
    """
    seen, out = {}, set()
    for heading in re.findall(r'^#{1,6}\s+(.*?)\s*#*\s*$', _strip_fences(text), re.M):
        slug = re.sub(r'[^\w\- ]', '', heading.strip().lower()).replace(' ', '-')
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f'{slug}-{n}')
    return out


def _strip_fences(text: str) -> str:
    return re.sub(r'^```.*?^```', '', text, flags=re.S | re.M)


def broken_links(path: str, root: str = ROOT) -> List[str]:
    """One line per link of ``path`` that does not resolve (file, or file and anchor)."""
    with open(path) as f:
        text = f.read()
    rel = os.path.relpath(path, root)
    problems = []
    for target in _LINK.findall(_strip_code(text)) + _REF.findall(_strip_fences(text)):
        if re.match(r'^[a-z][a-z0-9+.-]*:', target, re.I):      # http:, https:, mailto:
            continue
        file_part, _, anchor = target.partition('#')
        dest = (os.path.normpath(os.path.join(os.path.dirname(path), file_part)) if file_part
                else path)
        dest_rel = os.path.relpath(dest, root)
        if not os.path.exists(dest):
            problems.append(f'{rel}: link {target} -> {dest_rel} does not exist')
            continue
        if anchor and dest.endswith('.md'):
            with open(dest) as f:
                if anchor.lower() not in anchors(f.read()):
                    problems.append(f'{rel}: link {target} -> no heading #{anchor} in {dest_rel}')
    return problems


def _pages() -> List[str]:
    return ([os.path.join(ROOT, 'README.md')]
            + sorted(glob.glob(os.path.join(ROOT, 'docs', '*.md'))))


def test_every_relative_link_resolves():
    problems = [p for page in _pages() for p in broken_links(page)]
    assert not problems, '\n'.join(problems)


def test_the_readme_links_the_docs_it_points_to():
    """The README sends readers to docs/ by links (clickable), not by bare paths only."""
    with open(os.path.join(ROOT, 'README.md')) as f:
        linked = set(_LINK.findall(_strip_code(f.read())))
    assert {'docs/commands.md', 'docs/results.md', 'docs/parameters.md',
            'docs/benchmarks.md', 'docs/running.md'} <= linked


def test_a_broken_file_or_anchor_is_named(tmp_path):
    """
    Check that the checker names a missing page and a missing heading.

    A missing page and a missing heading are each reported by name, a good link and an external
    one are not.
    """
    (tmp_path / 'docs').mkdir()
    (tmp_path / 'docs' / 'a.md').write_text(
        '# Page A\n\n## Run the demo (2 s)\n\n## Run the demo (2 s)\n')
    readme = tmp_path / 'README.md'
    readme.write_text('[ok](docs/a.md#run-the-demo-2-s) [ok2](docs/a.md#run-the-demo-2-s-1) '
                      '[web](https://example.org/x.md) `[code](nowhere.md)`\n'
                      '[gone](docs/b.md) [bad anchor](docs/a.md#run-it)\n\n[ref]: docs/c.md\n')
    problems = broken_links(str(readme), str(tmp_path))
    assert problems == ['README.md: link docs/b.md -> docs/b.md does not exist',
                        'README.md: link docs/a.md#run-it -> no heading #run-it in docs/a.md',
                        'README.md: link docs/c.md -> docs/c.md does not exist']
