"""Regenerate the tables of docs/rig_contract.md from seft_msgs_py.rig_contract.

Usage: .venv/bin/python tools/gen_rig_contract_docs.py   (tests check the page is current)
"""

from pathlib import Path

from seft_msgs_py import rig_contract

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / 'docs' / 'rig_contract.md'
BEGIN, END = '<!-- rig-contract:begin -->', '<!-- rig-contract:end -->'


def page_with_tables(text: str) -> str:
    """`text` with the block between the markers replaced by the contract's tables."""
    i, j = text.index(BEGIN) + len(BEGIN), text.index(END)
    return text[:i] + '\n' + rig_contract.markdown_tables() + '\n' + text[j:]


def main() -> None:
    PAGE.write_text(page_with_tables(PAGE.read_text()))


if __name__ == '__main__':
    main()
