"""A JPEG's scans, counted from its markers before a pixel is decoded.

libjpeg decodes a progressive JPEG scan by scan, and each scan is a pass over every block of the
picture however few bytes it holds: a scan that refines nothing is 12 bytes, so an 8 KB frame of
600 of them costs as much as 600 frames. The count of scans, not the file's size, bounds that
work, and reading it costs a walk over the segment headers (the scans' data is skipped by a
search for the next marker). A sequential JPEG whose first scan holds every component (what
cameras and Pillow write) is one scan: libjpeg refuses any scan after it, so the walk stops
there without searching its data."""

from __future__ import annotations

import re

from imitation.limits import LIMITS, over_limit

_SOI, _EOI, _SOS = 0xD8, 0xD9, 0xDA
_SEQUENTIAL = {0xC0, 0xC1, 0xC9}  # SOF markers of sequential DCT (baseline, extended, arithmetic)
_WITHOUT_LENGTH = {0x01, *range(0xD0, 0xD8)}  # TEM and the restart markers RST0-7
# In a scan's data 0xFF is followed by 0x00 (a stuffed byte) or a restart marker; a marker that
# ends the scan is 0xFF followed by anything else (0xFF itself is fill before a marker).
_END_OF_SCAN = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")


def scan_count(data: bytes | memoryview) -> int:
    """How many scans (SOS markers) the JPEG `data` holds before its EOI. A segment's contents
    (an Exif thumbnail in APP1, say) are skipped by its length; the count stops where the bytes
    are not a marker, which the decoder then refuses on its own."""
    view = memoryview(data).cast("B")
    size = len(view)
    if size < 2 or view[0] != 0xFF or view[1] != _SOI:
        return 0
    scans, position = 0, 2
    sequential_components = 0  # components of a sequential frame's SOF; 0 for any other frame
    while position + 4 <= size:
        if view[position] != 0xFF:
            break
        marker = view[position + 1]
        if marker == 0xFF:  # fill byte
            position += 1
            continue
        if marker == _EOI:
            break
        if marker in _WITHOUT_LENGTH:
            position += 2
            continue
        segment = position + 4
        position += 2 + ((view[position + 2] << 8) | view[position + 3])
        if marker in _SEQUENTIAL and segment + 5 < size:
            sequential_components = view[segment + 5]  # after precision, height and width
        if marker == _SOS:
            scans += 1
            if scans == 1 and sequential_components and segment < size and view[segment] == sequential_components:
                break  # every component in one sequential scan: the image is whole after it
            end = _END_OF_SCAN.search(view, position)
            if end is None:
                break
            position = end.start()
    return scans


def excess_scans(data: bytes | memoryview) -> str | None:
    """Why the JPEG `data` must not be decoded (more scans than the limit `jpeg_scans`), or None."""
    scans = scan_count(data)
    if scans <= LIMITS.jpeg_scans:
        return None
    return str(over_limit("scans of one JPEG frame", scans, "jpeg_scans"))
