"""JPEG files no everyday encoder writes, made by hand for the tests (ITU-T T.81).

- :func:`lossless_jpeg`: a lossless (SOF3) greyscale JPEG, predictor 1 (left neighbour), which
  libjpeg-turbo 3 (OpenCV's) decodes and libjpeg-turbo 2.1 (the window decoder's) does not.
- :func:`twelve_bit_jpeg`: a 12-bit (SOF1) greyscale JPEG whose blocks are flat (DC only).
- :func:`incomplete_progressive`: a progressive JPEG cut after its first scans and closed with an
  end-of-image marker, a legal file (a decoder shows what the scans it has give).
"""

from __future__ import annotations

import struct

import numpy as np


class _Bits:
    """Entropy-coded data: bits MSB first, a 0x00 stuffed after every 0xFF, padded with 1s."""

    def __init__(self) -> None:
        self.out = bytearray()
        self.acc = 0
        self.n = 0

    def put(self, code: int, length: int) -> None:
        for i in range(length - 1, -1, -1):
            self.acc = (self.acc << 1) | ((code >> i) & 1)
            self.n += 1
            if self.n == 8:
                self.out.append(self.acc)
                if self.acc == 0xFF:
                    self.out.append(0)
                self.acc = self.n = 0

    def flush(self) -> bytes:
        while self.n:
            self.put(1, 1)
        return bytes(self.out)


def _segment(marker: int, body: bytes) -> bytes:
    return struct.pack(">BBH", 0xFF, marker, len(body) + 2) + body


def _huffman_table(table_class: int, table_id: int, symbols: list[int], length: int):
    """A DHT segment giving every symbol a code of ``length`` bits, and the codes."""
    counts = [0] * 16
    counts[length - 1] = len(symbols)
    body = bytes([table_class << 4 | table_id, *counts, *symbols])
    return _segment(0xC4, body), {s: (i, length) for i, s in enumerate(symbols)}


def _magnitude(value: int) -> tuple[int, int]:
    """(category, extra bits) of a difference: T.81 F.1.2.1 / H.1.2.2."""
    category = abs(value).bit_length()
    bits = value if value >= 0 else value + (1 << category) - 1
    return category, bits


def lossless_jpeg(image: np.ndarray) -> bytes:
    """A lossless (SOF3) 8-bit JPEG of ``image`` (uint8 H×W grey, or H×W×3 RGB: components named
    R, G, B, which libjpeg reads as RGB), predictor 1, non-interleaved scans."""
    planes = [image] if image.ndim == 2 else [image[..., i] for i in range(3)]
    height, width = planes[0].shape
    ids = [1] if len(planes) == 1 else list(b"RGB")
    dht, codes = _huffman_table(0, 0, list(range(9)), 4)
    components = b"".join(bytes([i, 0x11, 0]) for i in ids)
    sof = struct.pack(">BHHB", 8, height, width, len(planes)) + components
    out = b"\xff\xd8" + _segment(0xC3, sof) + dht
    for component, plane in zip(ids, planes, strict=True):
        out += _segment(0xDA, bytes([1, component, 0x00, 1, 0, 0]))  # predictor 1, Pt 0
        bits = _Bits()
        x = plane.astype(np.int64)
        for r in range(height):
            for c in range(width):
                if r == 0 and c == 0:
                    prediction = 128  # 2 ** (P - 1)
                elif c == 0:
                    prediction = x[r - 1, c]  # the first column predicts from above
                else:
                    prediction = x[r, c - 1]
                category, extra = _magnitude(int(x[r, c] - prediction))
                bits.put(*codes[category])
                bits.put(extra, category)
        out += bits.flush()
    return out + b"\xff\xd9"


def twelve_bit_jpeg(block_means: np.ndarray) -> bytes:
    """A 12-bit (SOF1) greyscale JPEG of flat 8×8 blocks with these means (0..4095)."""
    rows, cols = block_means.shape
    dqt = _segment(0xDB, bytes([0]) + bytes([1] * 64))  # every quantiser 1
    dc_table, dc = _huffman_table(0, 0, list(range(16)), 5)
    ac_table, ac = _huffman_table(1, 0, [0x00], 1)  # end-of-block only
    sof = struct.pack(">BHHB", 12, rows * 8, cols * 8, 1) + b"\x01\x11\x00"
    header = b"\xff\xd8" + dqt + _segment(0xC1, sof) + dc_table + ac_table
    sos = _segment(0xDA, bytes([1, 1, 0x00, 0, 63, 0]))
    bits, previous = _Bits(), 0
    for value in block_means.ravel():
        coefficient = (int(value) - 2048) * 8  # F(0,0) = 8 × mean, level-shifted
        category, extra = _magnitude(coefficient - previous)
        previous = coefficient
        bits.put(*dc[category])
        bits.put(extra, category)
        bits.put(*ac[0x00])
    return header + sos + bits.flush() + b"\xff\xd9"


def scan_starts(data: bytes) -> list[int]:
    """Where each start-of-scan marker of a JPEG is (segments walked, not searched for)."""
    starts, pos = [], 2
    while pos < len(data):
        marker = data[pos + 1]
        if marker == 0xD9:
            break
        if marker == 0xDA:
            starts.append(pos)
            pos += 2 + struct.unpack(">H", data[pos + 2 : pos + 4])[0]
            while not (data[pos] == 0xFF and data[pos + 1] not in (0x00, *range(0xD0, 0xD8))):
                pos += 1  # the entropy-coded data, up to the next marker
            continue
        pos += 2 + struct.unpack(">H", data[pos + 2 : pos + 4])[0]
    return starts


def incomplete_progressive(data: bytes, scans: int) -> bytes:
    """A progressive JPEG's first ``scans`` scans, then an end-of-image marker."""
    starts = scan_starts(data)
    assert 0 < scans < len(starts), (scans, len(starts))
    return data[: starts[scans]] + b"\xff\xd9"
