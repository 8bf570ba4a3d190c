"""The simulated receiver's serial port: a pseudo-terminal the GNSS driver reads as it would a
receiver's port (`ares run --wire`).

`NmeaPty(link)` opens a pseudo-terminal pair in raw mode (no echo, no line-end translation: the
bytes arrive as written), and makes `link` a symbolic link to its slave side, the "serial port"
the driver opens (vehicle_io.gnss.device); `read()` gives what the driver wrote to it (the RTK
corrections a receiver takes on its port). `write(lines)` writes sentences CRLF-terminated to the
master side without ever blocking: when nobody reads and the terminal's buffer is full, what does
not fit is dropped and counted (`dropped_lines`), so the simulator never stalls on its reader.
"""

from __future__ import annotations

import os
import tty
from pathlib import Path


class NmeaPty:
    """A pseudo-terminal with a stable name (`link`) for the driver, written by the simulator."""

    def __init__(self, link: str | Path):
        self.link = Path(link)
        self.master, self._slave = os.openpty()
        # the slave stays open here: the terminal keeps its raw settings and does not hang up
        # while the driver closes and reopens it
        tty.setraw(self._slave)
        os.set_blocking(self.master, False)
        self.slave_name = os.ttyname(self._slave)
        self.written_lines = 0
        self.dropped_lines = 0
        self.link.parent.mkdir(parents=True, exist_ok=True)
        if self.link.exists() and not self.link.is_symlink():
            self.close()
            raise FileExistsError(f"{self.link} exists and is not a link: not replaced by the simulated receiver")
        temporary = self.link.with_name(f".{self.link.name}.{os.getpid()}")
        temporary.unlink(missing_ok=True)
        temporary.symlink_to(self.slave_name)
        os.replace(temporary, self.link)  # a stale link is replaced in one step

    def write(self, lines: list[str]) -> int:
        """Writes the sentences, each with CRLF; returns how many were dropped for want of room."""
        data = "".join(f"{line}\r\n" for line in lines).encode("ascii", "replace")
        done = 0
        while done < len(data):
            try:
                done += os.write(self.master, data[done:])
            except (BlockingIOError, InterruptedError):
                break  # the reader is not keeping up (or absent): the rest is lost, as on a real port
            except OSError:
                break
        if done == len(data):
            self.written_lines += len(lines)
            return 0
        sent = data[:done].count(b"\n")  # whole lines written; a cut one counts as dropped
        dropped = len(lines) - sent
        self.written_lines += sent
        self.dropped_lines += dropped
        return dropped

    def read(self) -> bytes:
        """What the driver wrote to the receiver's port (its RTK corrections), without waiting."""
        chunks = []
        while True:
            try:
                data = os.read(self.master, 65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # nobody has the port open: nothing was written
                break
            if not data:
                break
            chunks.append(data)
        return b"".join(chunks)

    def close(self) -> None:
        """Removes the link (if it is still ours) and closes the terminal."""
        try:
            if self.link.is_symlink() and os.readlink(self.link) == self.slave_name:
                self.link.unlink()
        except OSError:
            pass
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
