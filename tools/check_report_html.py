"""Check that a seft report.html is one self-contained page; screenshot it where a browser is.

Usage: .venv/bin/python tools/check_report_html.py REPORT_HTML [--screenshot PNG]

Always: parses the page with the standard library (``seft_ros.analysis.htmlreport.check_html``)
and fails (exit 1) unless every <img> is an embedded ``data:`` URI, nothing is fetched from
elsewhere, and the criteria table and the parameters are there. With ``--screenshot``: renders
the page offline in a headless chromium or chrome (Debian's ``chromium``) and writes a PNG;
where none is installed it says so and skips that step (exit 0).
"""

import argparse
from pathlib import Path
import shutil
import subprocess
import sys

from seft_ros.analysis.htmlreport import check_html

BROWSERS = ('chromium', 'chromium-browser', 'google-chrome', 'google-chrome-stable')
REQUIRED_HEADINGS = ('Evaluation criteria (RTHS benchmark)', 'Parameters and software')


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('html', type=Path)
    parser.add_argument('--screenshot', type=Path, metavar='PNG')
    args = parser.parse_args(argv)
    check = check_html(args.html.read_text(encoding='utf-8'))
    print(f'{args.html}: {check.images} images ({check.embedded_images} embedded), '
          f'{check.tables} tables, {len(check.external)} external references')
    problems = [f'external reference: {ref}' for ref in check.external]
    if check.images != check.embedded_images:
        problems.append(f'{check.images - check.embedded_images} images not embedded')
    problems += [f'missing section: {h}' for h in REQUIRED_HEADINGS if h not in check.headings]
    if check.tables < 2:
        problems.append(f'{check.tables} tables; expected the criteria and the parameters')
    for line in problems:
        print(f'FAIL: {line}')
    if problems:
        return 1
    if args.screenshot:
        browser = next((shutil.which(b) for b in BROWSERS if shutil.which(b)), None)
        if browser is None:
            print(f'no headless browser installed ({", ".join(BROWSERS)}): screenshot skipped')
            return 0
        subprocess.run([browser, '--headless', '--no-sandbox', '--disable-gpu',
                        '--window-size=1400,4000', f'--screenshot={args.screenshot.resolve()}',
                        args.html.resolve().as_uri()], check=True, timeout=120)
        print(f'screenshot: {args.screenshot}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
