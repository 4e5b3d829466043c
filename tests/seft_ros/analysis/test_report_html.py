"""report.html: one self-contained page (figures embedded), with the criteria, the parameters
and the software version; the Markdown-subset renderer and the checker on small inputs; a
screenshot in a real headless browser where one is installed."""

import base64
import shutil
import subprocess

import numpy as np
import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import InputError
from seft_ros.analysis.htmlreport import check_html, markdown_to_html
from seft_ros.analysis.report import write_report
from seft_ros.core.experiment import simulate

#: A 1x1 PNG.
PNG = base64.b64decode('iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNk'
                       '+M9QDwADhgGAWjR9awAAAABJRU5ErkJggg==')
BROWSERS = ('chromium', 'chromium-browser', 'google-chrome', 'google-chrome-stable')


@pytest.fixture(scope='module')
def sweep(tmp_path_factory):
    """Four short simulated runs of the default record: alpha 0 and 1, 'none' and 'model'."""
    runs = []
    for predictor in ('none', 'model'):
        for alpha in (0.0, 1.0):
            p = parameters.resolve({'alpha': alpha, 'predictor': predictor,
                                    'rig_model': 'servohydraulic', 'amplitude_N': 500.0,
                                    'duration_s': 3.0})
            runs.append(simulate(p))
    out = tmp_path_factory.mktemp('html') / 'report'
    return runs, write_report(runs, out, title='html sweep')


def test_report_html_is_self_contained_with_tables_and_figures(sweep):
    runs, paths = sweep
    assert paths.report_html == paths.out_dir / 'report.html'
    text = paths.report_html.read_text(encoding='utf-8')
    check = check_html(text)
    assert check.self_contained, check.external
    markdown = paths.report_md.read_text(encoding='utf-8')
    # every figure of report.md, embedded; the PNG files themselves are not referenced
    assert check.images == markdown.count('](') == len(paths.figures) >= 6
    assert 'src="criteria_vs_alpha.png"' not in text
    assert paths.criteria_png.name in markdown and paths.runs_png.name in markdown
    # criteria table, best-run table, per-alpha tables, per-run tables, parameters
    assert check.tables >= 1 + 1 + 2 + len(runs) + 2
    for heading in ('html sweep', 'Evaluation criteria (RTHS benchmark)',
                    'Parameters and software'):
        assert heading in check.headings
    assert '<th class="r">J1 [ms]</th>' in text and '<th class="r">J5 [%]</th>' in text
    assert 'seft_ros 0.1' in text and 'alpha' in text
    # the parameters that differ, one column per run
    assert '<td><code>predictor</code></td>' in text


def test_criteria_table_rows_are_the_runs(sweep):
    runs, paths = sweep
    markdown = paths.report_md.read_text(encoding='utf-8')
    section = markdown.split('## Evaluation criteria (RTHS benchmark)')[1].split('\n## ')[0]
    rows = [line for line in section.splitlines() if line.startswith('| ') and
            line[2].isdigit()]
    assert len(rows) == len(runs)
    assert '| 1 | 0 | servohydraulic | none |' in rows[0]
    assert '| 4 | 1 | servohydraulic | model |' in rows[3]


def test_two_runs_of_one_record_get_the_side_by_side_figure(sweep, tmp_path):
    runs, _ = sweep
    paths = write_report([runs[1], runs[3]], tmp_path)   # alpha 1: none and model
    assert paths.runs_png is not None and paths.runs_png.read_bytes()[:4] == b'\x89PNG'
    assert paths.criteria_png is None                    # one alpha: no plot against alpha
    check = check_html(paths.report_html.read_text(encoding='utf-8'))
    assert check.self_contained and check.images == len(paths.figures)


def test_markdown_subset(tmp_path):
    (tmp_path / 'f.png').write_bytes(PNG)
    md = '\n'.join([
        '# Title', '', 'A paragraph with **bold** and `code`', 'on two lines <b>escaped</b>.',
        '', '- item one', '- **item** two', '  - nested', '- item three', '',
        '| a | b |', '|---|---:|', '| 1 | 2.5 |', '', '![a figure](f.png)', ''])
    text = markdown_to_html(md, base_dir=tmp_path)
    check = check_html(text)
    assert check.self_contained and check.images == 1 and check.tables == 1
    assert check.headings == ['Title'] and '<title>Title</title>' in text
    assert '<strong>bold</strong>' in text and '<code>code</code>' in text
    assert '&lt;b&gt;escaped&lt;/b&gt;' in text
    assert '<li><strong>item</strong> two\n<ul>\n<li>nested</li>\n</ul></li>' in text
    assert '<td class="r">2.5</td>' in text and '<td>1</td>' in text
    assert text.count('<p>') == 1


def test_markdown_image_errors(tmp_path):
    with pytest.raises(InputError, match='missing.png: cannot read the figure'):
        markdown_to_html('![x](missing.png)', base_dir=tmp_path)
    (tmp_path / 'f.gif').write_bytes(b'GIF89a')
    with pytest.raises(InputError, match='cannot embed a .gif file'):
        markdown_to_html('![x](f.gif)', base_dir=tmp_path)


def test_check_html_flags_what_the_page_would_fetch():
    check = check_html('<html><head><link rel="stylesheet" href="https://x/s.css">'
                       '<style>body { background: url(bg.png) }</style></head><body>'
                       '<img src="fig.png"><img src="data:image/png;base64,AAAA">'
                       '<a href="#top">top</a></body></html>')
    assert check.images == 2 and check.embedded_images == 1
    assert check.external == ['https://x/s.css', 'bg.png', 'fig.png']
    assert not check.self_contained


def test_report_html_in_a_headless_browser(sweep, tmp_path):
    """Debian's chromium renders the page offline and takes a screenshot."""
    browser = next((shutil.which(b) for b in BROWSERS if shutil.which(b)), None)
    if browser is None:
        pytest.skip(f'no headless browser installed (looked for {", ".join(BROWSERS)})')
    _, paths = sweep
    shot = tmp_path / 'report.png'
    proc = subprocess.run([browser, '--headless', '--no-sandbox', '--disable-gpu',
                           '--window-size=1400,3000', f'--screenshot={shot}',
                           paths.report_html.as_uri()], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert shot.read_bytes()[:4] == b'\x89PNG'
    # not a blank page: the screenshot has more than one colour
    from matplotlib.image import imread
    assert np.unique(imread(shot).reshape(-1, 4), axis=0).shape[0] > 10
