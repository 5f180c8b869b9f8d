"""Lines in the phone's format, as the tests need them."""

from __future__ import annotations

from app.stream.protocol import ParseError, parse_line


def parses(line: bytes) -> bool:
    """Whether the parser takes this line (what a recording keeps of a stream)."""
    try:
        parse_line(line.decode("utf-8", "replace"))
    except ParseError:
        return False
    return True
