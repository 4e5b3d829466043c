"""Regenerate the tables of docs/rig_contract.md: the contract's (seft_msgs_py.rig_contract)
and the UDP bridge's byte layout (seft_plant_sim.udp_layout).

Usage: .venv/bin/python tools/gen_rig_contract_docs.py   (tests check the page is current)
"""

from pathlib import Path

from seft_msgs_py import rig_contract
from seft_plant_sim import udp_layout

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / 'docs' / 'rig_contract.md'
#: marker name -> the tables between its markers
BLOCKS = {'rig-contract': rig_contract.markdown_tables, 'udp-layout': udp_layout.markdown_tables}


def page_with_tables(text: str) -> str:
    """`text` with each block between its markers replaced by its tables."""
    for name, tables in BLOCKS.items():
        begin, end = f'<!-- {name}:begin -->', f'<!-- {name}:end -->'
        if begin not in text:
            continue
        i, j = text.index(begin) + len(begin), text.index(end)
        text = text[:i] + '\n' + tables() + '\n' + text[j:]
    return text


def main() -> None:
    PAGE.write_text(page_with_tables(PAGE.read_text()))


if __name__ == '__main__':
    main()
