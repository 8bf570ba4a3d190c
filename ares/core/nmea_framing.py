"""NMEA 0183 framing, shared by whoever writes or reads sentences (the simulated receiver, the
GNSS node's parser): `$<body>*<checksum>`, the checksum the XOR of the body's characters."""

from __future__ import annotations


def checksum(body: str) -> str:
    """XOR of every character between '$' and '*', as two upper-case hex digits."""
    cs = 0
    for ch in body:
        cs ^= ord(ch)
    return f"{cs:02X}"


def sentence(body: str) -> str:
    """'$' + body + '*' + checksum (no line ending)."""
    return f"${body}*{checksum(body)}"
