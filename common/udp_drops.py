"""How many datagrams the kernel dropped for one UDP socket: its receive buffer was full.

A datagram the kernel drops never reaches `recv`: the live pose receiver (the video scheduler)
lost 114 of 2,060 in a burst without a trace. Linux counts them per socket in the `drops`
column of /proc/net/udp (udp6 for IPv6), found by the socket's inode; elsewhere the count is
unknown (None). Reading the table costs one small file read, so callers ask when they report,
not on every packet.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path

TABLES = (Path("/proc/net/udp"), Path("/proc/net/udp6"))


def kernel_drops(sock: socket.socket) -> int | None:
    """Datagrams dropped on `sock` since it was made, or None when this system does not say
    (not Linux, no /proc, or a closed socket)."""
    if sock.fileno() < 0:
        return None
    inode = str(os.fstat(sock.fileno()).st_ino)
    for table in TABLES:
        try:
            lines = table.read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            # sl local rem st tx:rx tr:tm retrnsmt uid timeout inode ref pointer drops
            if len(fields) >= 13 and fields[9] == inode:
                try:
                    return int(fields[12])
                except ValueError:
                    return None
    return None
