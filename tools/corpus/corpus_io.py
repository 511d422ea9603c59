"""Pure-Python image writers and statistics for the corpus (Blender's Python here has no numpy).

Blender 3.4 writes every OpenEXR as RGB or RGBA (its colour mode 'BW' is ignored for EXR), and the
corpus wants 1-channel float EXRs, so this module writes them itself: a single-part scanline EXR
(OpenEXR file layout, openexr.com/en/latest/OpenEXRFileLayout.html) with ZIP compression.
Rows given to the writers are top-down; Blender's pixel buffers are bottom-up (see flip_rows).
"""

import array
import math
import os
import struct
import zlib


def _atomic_write(path, data):
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def flip_rows(values, width, height, channels):
    """Bottom-up rows (Blender) to top-down rows (files), or back."""
    row = width * channels
    out = array.array(values.typecode if isinstance(values, array.array) else "f")
    for y in range(height - 1, -1, -1):
        out.extend(values[y * row:(y + 1) * row])
    return out


def write_png(path, width, height, channels, data):
    """8-bit PNG, grey (1 channel) or RGB (3); data: top-down bytes, width*height*channels."""
    if channels not in (1, 3) or len(data) != width * height * channels:
        raise ValueError("%s: bad PNG buffer (%d bytes for %dx%dx%d)" %
                         (path, len(data), width, height, channels))
    row = width * channels
    raw = b"".join(b"\x00" + bytes(data[y * row:(y + 1) * row]) for y in range(height))

    def chunk(tag, body):
        return (struct.pack(">I", len(body)) + tag + body +
                struct.pack(">I", zlib.crc32(tag + body) & 0xFFFFFFFF))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0 if channels == 1 else 2, 0, 0, 0)
    # sRGB chunk (rendering intent 0): the values are sRGB-encoded 8-bit, as Blender writes them.
    srgb = chunk(b"sRGB", b"\x00") if channels == 3 else b""
    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + srgb +
           chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))
    _atomic_write(path, png)


def _exr_attr(name, type_name, value):
    return (name.encode() + b"\x00" + type_name.encode() + b"\x00" +
            struct.pack("<i", len(value)) + value)


def _zip_block(raw):
    """OpenEXR ZIP: bytes split into even/odd halves, then a delta predictor, then zlib."""
    t = raw[0::2] + raw[1::2]
    d = bytearray(len(t))
    d[0] = t[0]
    d[1:] = bytes((b - a + 128) & 0xFF for a, b in zip(t, t[1:]))
    return zlib.compress(bytes(d), 6)


def write_exr_1ch(path, width, height, values, channel="Y"):
    """1-channel 32-bit float scanline EXR; values: top-down floats, width*height."""
    if len(values) != width * height:
        raise ValueError("%s: bad EXR buffer (%d values for %dx%d)" %
                         (path, len(values), width, height))
    chlist = channel.encode() + b"\x00" + struct.pack("<iB3xii", 2, 0, 1, 1) + b"\x00"
    box = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    header = (_exr_attr("channels", "chlist", chlist) +
              _exr_attr("compression", "compression", b"\x03") +  # ZIP, 16 lines a block
              _exr_attr("dataWindow", "box2i", box) + _exr_attr("displayWindow", "box2i", box) +
              _exr_attr("lineOrder", "lineOrder", b"\x00") +
              _exr_attr("pixelAspectRatio", "float", struct.pack("<f", 1.0)) +
              _exr_attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0)) +
              _exr_attr("screenWindowWidth", "float", struct.pack("<f", 1.0)) + b"\x00")
    floats = array.array("f", values)
    if struct.pack("=I", 1) != struct.pack("<I", 1):
        floats.byteswap()
    buf = floats.tobytes()
    lines = 16
    nblocks = (height + lines - 1) // lines
    head = struct.pack("<ii", 20000630, 2) + header  # magic, version 2 (single-part scanline)
    offset = len(head) + 8 * nblocks
    table, blocks = [], []
    for b in range(nblocks):
        y0, y1 = b * lines, min(height, (b + 1) * lines)
        raw = buf[y0 * width * 4:y1 * width * 4]
        z = _zip_block(raw)
        data = z if len(z) < len(raw) else raw  # a block no smaller than raw is stored raw
        block = struct.pack("<ii", y0, len(data)) + data
        table.append(offset)
        offset += len(block)
        blocks.append(block)
    _atomic_write(path, head + struct.pack("<%dQ" % nblocks, *table) + b"".join(blocks))


def percentile(sorted_values, q):
    """Nearest-rank percentile of an already sorted sequence, q in [0, 100]."""
    if not sorted_values:
        return float("nan")
    i = min(len(sorted_values) - 1, max(0, int(math.ceil(q / 100.0 * len(sorted_values))) - 1))
    return sorted_values[i]


def radius_stats(values, big=3.0):
    """median, p90, max and the share of pixels with a blur radius >= big px."""
    s = sorted(values)
    return {"median": round(percentile(s, 50), 3), "p90": round(percentile(s, 90), 3),
            "max": round(s[-1], 3) if s else float("nan"),
            "frac_ge_%gpx" % big: round(sum(1 for v in s if v >= big) / max(1, len(s)), 4)}
