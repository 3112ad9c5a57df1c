"""The README's CAN reason-code table is the code's: a team wires its CAN decoder from it."""

import re
from pathlib import Path

from terrainml.stream.transports.sinks import REASON_CODES, UNKNOWN_REASON_CODE

README = Path(__file__).resolve().parents[2] / "README.md"


def test_readme_reason_codes_are_the_sinks_codes():
    text = README.read_text()
    block = text[text.index("Reason codes:"):]
    block = block[:block.index(".\n")]
    listed = dict((name, int(code)) for code, name in re.findall(r"(\d+) `?([a-z_]+|none)`?", block))
    assert listed.pop("a") == UNKNOWN_REASON_CODE  # "63 a reason this table does not know"
    assert listed == {("none" if k == "" else k): v for k, v in REASON_CODES.items()}
    assert "bits 2-7 reason code" in text  # 6 bits: codes up to 63
