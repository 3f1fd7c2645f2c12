"""The user documentation: generated parameter list up to date, no dead links, README short."""

import re
from pathlib import Path
from urllib.parse import unquote

import pytest

from planar_vo.core import config

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / 'README.md'
DOCS = [*sorted((ROOT / 'docs').glob('*.md')), ROOT / 'bags' / 'README.md']
# [text](target) and ![alt](target); the target ends at whitespace or ')'.
_LINK = re.compile(r'!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+"[^"]*")?\s*\)')
_FENCE = re.compile(r'^(```|~~~).*?^\1', re.S | re.M)
_HEADING = re.compile(r'^#{1,6}[ \t]+(.+?)[ \t#]*$', re.M)


def _anchors(page: Path) -> set[str]:
    """The anchors GitHub gives the headings of a Markdown ``page``.

    Lower case, punctuation but '-' and '_' dropped, spaces made '-'; a repeated heading gets
    '-1', '-2', ...
    """
    seen: dict[str, int] = {}
    anchors = set()
    for title in _HEADING.findall(_FENCE.sub('', page.read_text())):
        title = re.sub(r'\[([^\]]*)\]\([^)]*\)', r'\1', title).replace('`', '')  # links, code
        slug = re.sub(r'[^\w\- ]', '', title.strip().lower()).replace(' ', '-')
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        anchors.add(slug if count == 0 else f'{slug}-{count}')
    return anchors


def test_parameters_md_is_the_schema_rendered():
    """docs/parameters.md is generated; regenerate it after changing config.SCHEMA with
    python -c 'from planar_vo.core import config; print(config.schema_markdown(), end="")'
    > docs/parameters.md"""
    assert (ROOT / 'docs' / 'parameters.md').read_text() == config.schema_markdown(), (
        'docs/parameters.md is out of date: python -c \'from planar_vo.core import config; '
        'print(config.schema_markdown(), end="")\' > docs/parameters.md')


def test_every_parameter_is_in_parameters_md():
    text = config.schema_markdown()
    for param in config.SCHEMA:
        assert f'| `{param.name}` |' in text


@pytest.mark.parametrize('page', [README, *DOCS], ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_point_to_existing_files(page):
    text = _FENCE.sub('', page.read_text())
    dead = []
    for target in _LINK.findall(text):
        if re.match(r'^[a-z][a-z0-9+.-]*:', target, re.I) or target.startswith('#'):
            continue  # http(s):, mailto:, in-page anchors
        path = unquote(target.split('#', 1)[0])
        if not (page.parent / path).exists():
            dead.append(target)
    assert not dead, f'{page.name}: links to missing files: {dead}'


@pytest.mark.parametrize('page', [README, *DOCS], ids=lambda p: p.relative_to(ROOT).as_posix())
def test_links_to_a_section_find_its_heading(page):
    """``page.md#section`` and ``#section`` name a heading that is there (sections move)."""
    text = _FENCE.sub('', page.read_text())
    dead = []
    for target in _LINK.findall(text):
        path, _, anchor = unquote(target).partition('#')
        if not anchor or re.match(r'^[a-z][a-z0-9+.-]*:', target, re.I):
            continue
        linked = page if not path else page.parent / path
        if linked.suffix == '.md' and linked.exists() and anchor not in _anchors(linked):
            dead.append(target)
    assert not dead, f'{page.name}: links to sections that are not there: {dead}'


def test_readme_is_short_and_names_the_two_commands():
    text = README.read_text()
    assert len(text.splitlines()) < 260
    assert 'make demo' in text
    assert 'make test' in text


def test_every_figure_in_docs_is_linked():
    pages = '\n'.join(p.read_text() for p in [README, *DOCS])
    for figure in sorted((ROOT / 'docs').glob('*.png')):
        assert figure.name in pages, f'docs/{figure.name} is linked from no page'
