"""A self-contained HTML page from the report's Markdown, and a check that it is one.

Imports no rclpy. The report is written once, as Markdown (``report.md``); :func:`markdown_to_html`
turns the subset of Markdown the report uses (headings, paragraphs, bullet lists two levels
deep, pipe tables, images on their own line, ``**bold**`` and ```code```) into one HTML file
whose figures are embedded as base64 ``data:`` URIs, so the page needs no other file and no
network. :func:`check_html` verifies that on any HTML text with the standard library's
``html.parser``.
"""

import base64
from dataclasses import dataclass, field
import html
from html.parser import HTMLParser
from pathlib import Path
import re

from seft_msgs_py.errors import InputError

__all__ = ['markdown_to_html', 'check_html', 'HtmlCheck']

_IMAGE = re.compile(r'^!\[(?P<alt>[^\]]*)\]\((?P<src>[^)\s]+)\)\s*$')
_MIME = {'.png': 'image/png', '.svg': 'image/svg+xml', '.jpg': 'image/jpeg',
         '.jpeg': 'image/jpeg'}
_STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 90em; padding: 0 1em;
       color: #222; line-height: 1.4; }
h1 { font-size: 1.6em; } h2 { font-size: 1.3em; margin-top: 1.6em;
  border-bottom: 1px solid #ccc; } h3 { font-size: 1.1em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.5em; }
th { background: #eee; } tr:nth-child(even) td { background: #f7f7f7; }
td.r, th.r { text-align: right; font-variant-numeric: tabular-nums; }
img { max-width: 100%; height: auto; display: block; margin: 0.6em 0; }
code { background: #f2f2f2; padding: 0 0.2em; }
"""


def _inline(text: str) -> str:
    """Escape `text` and render ``**bold**`` and ```code```."""
    out = html.escape(text, quote=False)
    out = re.sub(r'`([^`]+)`', r'<code>\1</code>', out)
    return re.sub(r'\*\*(.+?)\*\*', r'<strong>\1</strong>', out)


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip('|').split('|')]


def _image(alt: str, src: str, base_dir: Path) -> str:
    path = Path(src) if Path(src).is_absolute() else base_dir / src
    mime = _MIME.get(path.suffix.lower())
    if mime is None:
        raise InputError(f'{path}: cannot embed a {path.suffix or "suffix-less"} file; '
                         f'expected one of {", ".join(sorted(_MIME))}')
    try:
        data = base64.b64encode(path.read_bytes()).decode('ascii')
    except OSError as exc:
        raise InputError(f'{path}: cannot read the figure ({exc.strerror})') from None
    return (f'<figure><img alt="{html.escape(alt)}" title="{html.escape(path.name)}" '
            f'src="data:{mime};base64,{data}"></figure>')


def _table(rows: list[str]) -> str:
    head = _cells(rows[0])
    align = _cells(rows[1]) if len(rows) > 1 else []
    right = [a.endswith(':') and not a.startswith(':') for a in align]
    body = rows[2:]

    def cls(j):
        return ' class="r"' if j < len(right) and right[j] else ''

    out = ['<table>', '<thead><tr>' + ''.join(f'<th{cls(j)}>{_inline(c)}</th>'
                                              for j, c in enumerate(head)) + '</tr></thead>',
           '<tbody>']
    for row in body:
        out.append('<tr>' + ''.join(f'<td{cls(j)}>{_inline(c)}</td>'
                                    for j, c in enumerate(_cells(row))) + '</tr>')
    out += ['</tbody>', '</table>']
    return '\n'.join(out)


def _list(items: list[str]) -> str:
    """Bullet items (``- `` at indent 0, ``  - `` one level deeper) as nested <ul>."""
    out = ['<ul>']
    depth = 0
    for line in items:
        level = 1 if line.startswith('  ') else 0
        text = _inline(line.strip()[2:])
        if level > depth:
            out[-1] = out[-1][:-len('</li>')]  # the sub-list goes inside the open item
            out.append('<ul>')
        elif level < depth:
            out.append('</ul></li>')
        depth = level
        out.append(f'<li>{text}</li>')
    if depth:
        out.append('</ul></li>')
    out.append('</ul>')
    return '\n'.join(out)


def markdown_to_html(markdown: str, *, base_dir, title: str = '') -> str:
    """Render the report's Markdown as one self-contained HTML page.

    Parameters
    ----------
    markdown : str
        The report (``report.md``), in the subset of Markdown described in the module.
    base_dir : str or Path
        Directory that relative image paths refer to (the report's directory).
    title : str
        The page's <title> (default: the first level-1 heading).

    Returns
    -------
    str
        An HTML5 document: inline CSS, every image a base64 ``data:`` URI, no reference to
        any other file or to the network.

    Raises
    ------
    InputError
        An image file is missing, unreadable or not PNG, SVG or JPEG.
    """
    base_dir = Path(base_dir)
    lines = markdown.split('\n')
    body: list[str] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        if not stripped:
            i += 1
            continue
        heading = re.match(r'^(#{1,6})\s+(.*)$', stripped)
        image = _IMAGE.match(stripped)
        if heading:
            level = len(heading.group(1))
            text = heading.group(2)
            if not title and level == 1:
                title = text
            body.append(f'<h{level}>{_inline(text)}</h{level}>')
            i += 1
        elif image:
            body.append(_image(image.group('alt'), image.group('src'), base_dir))
            i += 1
        elif stripped.startswith('|'):
            j = i
            while j < len(lines) and lines[j].strip().startswith('|'):
                j += 1
            body.append(_table([row.strip() for row in lines[i:j]]))
            i = j
        elif stripped.startswith('- '):
            j = i
            while j < len(lines) and (lines[j].startswith('- ') or lines[j].startswith('  - ')
                                      or (lines[j].startswith('  ') and lines[j].strip()
                                          and j > i)):
                j += 1
            items: list[str] = []
            for row in lines[i:j]:
                if row.lstrip().startswith('- '):
                    items.append(row)
                else:  # a continuation line of the previous item
                    items[-1] += ' ' + row.strip()
            body.append(_list(items))
            i = j
        else:
            j = i
            while j < len(lines) and lines[j].strip() and not (
                    lines[j].strip().startswith(('#', '|', '- '))
                    or _IMAGE.match(lines[j].strip())):
                j += 1
            j = max(j, i + 1)
            body.append('<p>' + _inline(' '.join(row.strip() for row in lines[i:j])) + '</p>')
            i = j
    return '\n'.join([
        '<!DOCTYPE html>', '<html lang="en">', '<head>', '<meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f'<title>{html.escape(title or "seft report")}</title>',
        f'<style>{_STYLE}</style>', '</head>', '<body>', *body, '</body>', '</html>', ''])


@dataclass
class HtmlCheck:
    """What :func:`check_html` found.

    Attributes
    ----------
    images : int
        Number of <img> elements.
    embedded_images : int
        Those whose ``src`` is a ``data:image/...;base64`` URI with a non-empty payload.
    tables : int
        Number of <table> elements.
    headings : list of str
        Text of the <h1>-<h3> headings, in order.
    external : list of str
        Every ``src``, ``href`` or CSS ``url(...)`` that is not a ``data:`` URI or a
        fragment (``#...``): what the page would fetch.
    """

    images: int = 0
    embedded_images: int = 0
    tables: int = 0
    headings: list[str] = field(default_factory=list)
    external: list[str] = field(default_factory=list)

    @property
    def self_contained(self) -> bool:
        """Every image embedded and nothing external."""
        return self.images == self.embedded_images and not self.external


class _Checker(HTMLParser):
    def __init__(self):
        super().__init__()
        self.result = HtmlCheck()
        self._heading: list[str] | None = None
        self._style = False

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == 'img':
            self.result.images += 1
            src = attrs.get('src') or ''
            if re.match(r'^data:image/[a-z+]+;base64,[A-Za-z0-9+/=]+$', src):
                self.result.embedded_images += 1
        elif tag == 'table':
            self.result.tables += 1
        elif tag in ('h1', 'h2', 'h3'):
            self._heading = []
        elif tag == 'style':
            self._style = True
        for name in ('src', 'href', 'data', 'poster'):
            value = attrs.get(name)
            if value and not value.startswith(('data:', '#')):
                self.result.external.append(value)

    def handle_endtag(self, tag):
        if tag in ('h1', 'h2', 'h3') and self._heading is not None:
            self.result.headings.append(''.join(self._heading).strip())
            self._heading = None
        elif tag == 'style':
            self._style = False

    def handle_data(self, data):
        if self._heading is not None:
            self._heading.append(data)
        if self._style:
            self.result.external += [u for u in re.findall(r'url\(([^)]*)\)', data)
                                     if not u.strip('\'" ').startswith('data:')]


def check_html(text: str) -> HtmlCheck:
    """Parse an HTML page and count its images, tables and external references.

    Parameters
    ----------
    text : str
        The HTML document.

    Returns
    -------
    HtmlCheck
        ``HtmlCheck.self_contained`` is True when every <img> is an embedded ``data:image``
        URI and no ``src``/``href`` or CSS ``url()`` points elsewhere.
    """
    checker = _Checker()
    checker.feed(text)
    checker.close()
    return checker.result
