"""Decoding input images into 8-bit BGR arrays, with clear errors for what cannot be used."""

from __future__ import annotations

import io
import os
import re
import stat
import struct
import tempfile
import threading
import warnings
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import IO, NamedTuple

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

NOT_AN_IMAGE = "not an image file (use JPEG, PNG, TIFF, WebP, BMP or GIF)"
# How each format signpose reads begins: a file that begins so and cannot be read is that format
# damaged (cut short by a copy or download, or corrupt), not some other kind of file.
SIGNATURES = {
    "JPEG": re.compile(rb"\xff\xd8\xff"),
    "PNG": re.compile(rb"\x89PNG\r\n\x1a\n"),
    "GIF": re.compile(rb"GIF8[79]a"),
    "TIFF": re.compile(rb"II\*\x00|MM\x00\*"),
    "WebP": re.compile(rb"RIFF.{4}WEBP", re.DOTALL),
    "BMP": re.compile(rb"BM.{4}\x00{4}", re.DOTALL),  # the size, then 4 reserved zero bytes: not just text "BM..."
}
# The brands an ISO base media file (HEIF's container) names in its leading ftyp box, for the
# HEIF images signpose cannot read: HEIC (HEVC-coded, iPhones' default) and AVIF (AV1-coded, which
# some builds of OpenCV read: it is refused only when it cannot be decoded). "mif1"/"msf1" name
# HEIF in general and come with AVIF's brands too, so AVIF's are looked for first.
_AVIF_BRANDS = frozenset([b"avif", b"avis", b"avio"])
_HEIF_BRANDS = frozenset([b"heic", b"heix", b"heim", b"heis", b"hevc", b"hevx", b"hevm", b"hevs", b"mif1", b"mif2",
                         b"msf1"])


# A JPEG marker: 0xFF and its code (any fill 0xFFs before it are not matched). Inside a scan's
# entropy-coded data 0xFF is a data byte only when a stuffed 0x00 follows it: anything else is a
# restart marker (RST0..7, 0xD0..0xD7) or the marker that ends the scan. With a single literal
# 0xFF first the search is fast (with "\xff+" first, to match fill bytes too, 20 times slower).
_MARKER = re.compile(rb"\xff([\x01-\xfe])")
# The markers that may follow a scan: tables (DHT, DAC, DQT), DRI, DNL, APPn, COM, the next scan
# (SOS) or the end of the image (EOI). 0x01 (TEM) and 0xD0..0xD7 (RSTn) stand alone, without a length.
_AFTER_SCAN = frozenset([0xC4, 0xCC, 0xDB, 0xDD, 0xDC, 0xFE, 0xDA, 0xD9, *range(0xE0, 0xF0)])
_STANDALONE = frozenset([0x01, *range(0xD0, 0xD8)])
# Start of frame markers, which give the components and their sampling factors (not DHT 0xC4, JPG 0xC8, DAC
# 0xCC); of them the progressive ones (Huffman and arithmetic coded), whose scans code each component's
# coefficients a band and some bits at a time.
_SOF = frozenset([0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF])
_PROGRESSIVE = frozenset([0xC2, 0xCA])
# Frames whose scans are Huffman coded (baseline, extended, progressive DCT): libjpeg decodes each
# from its data alone, to its last MCU. An arithmetic coder leaves out the zero bytes the decoder
# pads a scan with past its end, so filler there might change a scan's last decisions.
_HUFFMAN = frozenset([0xC0, 0xC1, 0xC2])
_ALL_COEFFICIENTS = (1 << 64) - 1  # a bit for each of a block's 64 coefficients, in zigzag order
_GARBLED = ": decoded, part of the picture would be grey or garbled"
# Entropy-coded data without 0xFF (no marker, no stuffing), which libjpeg decodes as blocks of
# varied levels, not flat grey: `missing_data` adds it after each scan to see if libjpeg ran short.
_FILLER = bytes(range(0xFF)) * 2
# EXIF orientations, and how each turns the pixels as stored into those shown (1, as stored, is not here):
# 3 a half turn, 6 and 8 a quarter turn clockwise and anticlockwise, 2 and 4 mirrored left-right and
# top-bottom, 5 and 7 mirrored across the main and the other diagonal.
ORIENTATIONS = range(1, 9)
_TURNS = {2: lambda im: cv2.flip(im, 1), 3: lambda im: cv2.rotate(im, cv2.ROTATE_180), 4: lambda im: cv2.flip(im, 0),
          5: cv2.transpose, 6: lambda im: cv2.rotate(im, cv2.ROTATE_90_CLOCKWISE),
          7: lambda im: cv2.rotate(cv2.transpose(im), cv2.ROTATE_180),
          8: lambda im: cv2.rotate(im, cv2.ROTATE_90_COUNTERCLOCKWISE)}
# What `read_file` calls what it refuses to open, by the file type its stat gives.
_NOT_FILES = {stat.S_IFDIR: "a directory", stat.S_IFIFO: "a named pipe (FIFO)", stat.S_IFSOCK: "a socket",
              stat.S_IFCHR: "a device", stat.S_IFBLK: "a device"}


# What decoders print on the process's stderr of an image or video signpose refuses, or reads, saying so in its own
# words: libjpeg's warnings on corrupt data, libpng's, OpenCV's log of a decode that failed (and the blank line
# after), and FFmpeg's log lines ("[mov,mp4,m4a,3gp,3g2,mj2 @ 0x55d0c1a2b3c0] moov atom not found", coloured
# when its first line went to a terminal).
_DECODER_CHATTER = re.compile(
    rb"^(?:Corrupt JPEG data|Premature end of JPEG file|Invalid SOS parameters|Inconsistent progression|"
    rb"Warning: unknown JFIF|libpng (?:warning|error)|\[ ?(?:WARN|ERROR):[^\]\n]*\] global (?:loadsave|grfmt)|"
    rb"(?:\x1b\[[0-9;]*m)?\[[^\]\n]+ @ 0x[0-9a-f]+\] )"
    rb"[^\n]*\n\n?", re.MULTILINE)


class _StderrCapture:
    """Keeps _DECODER_CHATTER off file descriptor 2 during decodes, on any number of threads at once.

    libjpeg and libpng print from C on descriptor 2, which no OpenCV setting reaches (OpenCV's log
    level would silence only its own lines), and the descriptor is one for the whole process. So it
    points at a temporary file while any decode runs: the first decode to begin points it there,
    the last to end points it back. A lock is held to count decodes and swap the descriptor, never
    during a decode, so decodes run in parallel. What else is written meanwhile (another thread's
    log) is written on to stderr, less the chatter, as each decode ends: whole lines, so that a
    line a decode is still writing is not cut in two, and all of it when the last one ends. With
    descriptor 2 closed there is no stderr to keep the chatter off, and decodes run without this.
    Costs about 0.03 ms a decode (dup, temporary file, pread); a 12 MP JPEG takes 70-85 ms to decode.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._decodes = 0  # running, while descriptor 2 points at _file
        self._file: IO[bytes] | None = None
        self._stderr = -1  # a duplicate of descriptor 2 as found, to write on to and point it back at
        self._sent = 0  # bytes of _file written on to stderr (or dropped as chatter)

    @contextmanager
    def capturing(self) -> Iterator[None]:
        """A context to decode in: what is written on descriptor 2 meanwhile goes to the capture."""
        with self._lock:
            captured = self._decodes > 0 or self._begin()
            if captured:
                self._decodes += 1
        try:
            yield
        finally:
            if captured:
                with self._lock:
                    self._decodes -= 1
                    if self._decodes:
                        self._send(whole_lines=True)
                    else:
                        self._end()

    def _begin(self) -> bool:
        """Point descriptor 2 at a new temporary file: True, or False when it is closed."""
        try:
            self._stderr = os.dup(2)
        except OSError:  # EBADF: closed
            return False
        try:  # only now: with descriptor 2 closed, the file would have been given it
            self._file = tempfile.TemporaryFile()
        except OSError:
            os.close(self._stderr)
            raise
        self._sent = 0
        os.dup2(self._file.fileno(), 2)
        return True

    def _end(self) -> None:
        """Point descriptor 2 back, write the rest of the capture on to it and drop the file."""
        assert self._file is not None  # opened by the decode that began the capture
        os.dup2(self._stderr, 2)
        try:
            self._send(whole_lines=False)
        finally:
            os.close(self._stderr)
            self._file.close()

    def _send(self, whole_lines: bool) -> None:
        """Write on to stderr, less the chatter, what was written to the capture since the last
        time: what ends a line, or all of it. Read with pread, which leaves the file offset the
        writers through descriptor 2 share where it is."""
        assert self._file is not None  # opened by the decode that began the capture
        fd = self._file.fileno()
        text = os.pread(fd, os.fstat(fd).st_size - self._sent, self._sent)
        if whole_lines:
            text = text[:text.rfind(b"\n") + 1]
        self._sent += len(text)
        text = _DECODER_CHATTER.sub(b"", text)
        while text:
            text = text[os.write(self._stderr, text):]


_STDERR_CAPTURE = _StderrCapture()


class ImageError(ValueError):
    """An input that is not a usable image; the message says why."""


class ImageTooLarge(ImageError):
    """An image whose pixel count exceeds the limit (a decompression bomb or a huge scan)."""


def image_format(data: bytes) -> str | None:
    """The format encoded image `data` begins as ("JPEG", "PNG", ... a key of SIGNATURES), or None."""
    return next((name for name, signature in SIGNATURES.items() if signature.match(data)), None)


def heif_kind(data: bytes) -> str | None:
    """"AVIF" or "HEIC" when `data` begins as a HEIF image file (an ftyp box naming one of the
    brands above), else None. Told by content: phones name HEIC files .heic, but a copy may be .jpg."""
    size = int.from_bytes(data[:4], "big")
    if data[4:8] != b"ftyp" or size < 16:
        return None
    # the major brand, a 4-byte minor version, then the compatible brands to the end of the box
    brands = {data[8:12], *(data[i:i + 4] for i in range(16, min(size, len(data), 256), 4))}
    return "AVIF" if brands & _AVIF_BRANDS else "HEIC" if brands & _HEIF_BRANDS else None


def unreadable(data: bytes, name: str) -> ImageError:
    """The error for `data`, the bytes of file `name`, that cannot be read as an 8-bit colour image:
    samples of a kind that has no 8-bit colour (floating point), a damaged or truncated file of its
    format when it begins as one, a HEIF image (HEIC, AVIF) with how to get one signpose reads,
    else not an image file at all."""
    kind = image_format(data)
    heif = heif_kind(data) if kind is None else None
    if heif == "HEIC":
        return ImageError(f"{name}: HEIC/HEIF images are not supported: export it as JPEG (on an iPhone, to take "
                          "JPEGs from now on: Settings > Camera > Formats > Most Compatible)")
    if heif == "AVIF":
        return ImageError(f"{name}: an AVIF image that cannot be read here (AVIF is not among the formats signpose "
                          "supports): export it as JPEG or PNG")
    if kind is None:
        return ImageError(f"{name}: {NOT_AN_IMAGE}")
    try:
        decoded = _imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        decoded = None
    if decoded is not None:
        return ImageError(f"{name}: a {kind} of {decoded.dtype} samples, which signpose does not read; "
                          "export it with 8- or 16-bit integer samples")
    return ImageError(f"{name}: damaged or truncated {kind} file (it begins as a {kind} but its image data cannot "
                      "be read); copy or export it again")


class ImageHeader(NamedTuple):
    media_type: str
    width: int  # px, as stored (before any EXIF rotation)
    height: int


def check_image_header(data: bytes, name: str, max_pixels: int) -> ImageHeader:
    """The media type and size of encoded image `data`, after checking its header says at most `max_pixels` px.

    Reads only the header (no pixel data is decoded), so a small file claiming a huge image
    is refused before it can take gigabytes of memory.
    """
    if not data:
        raise ImageError(f"{name}: file is empty")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as im:
                width, height = im.size
                media_type = im.get_format_mimetype() or "application/octet-stream"
    except Image.DecompressionBombError:  # past Pillow's own ceiling, which a higher max_pixels cannot lift
        raise _too_large(name, *_claimed_size(data, name), max_pixels) from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError):  # a header cut short, or no image
        raise unreadable(data, name) from None
    if width * height > max_pixels:
        raise _too_large(name, width, height, max_pixels)
    return ImageHeader(media_type, width, height)


def _too_large(name: str, width: int, height: int, max_pixels: int) -> ImageTooLarge:
    """The error for image `name` of `width` x `height` px, more than `max_pixels` px or Pillow's ceiling (twice
    Image.MAX_IMAGE_PIXELS, which it refuses to open): its size, and whether a higher --max-megapixels would let it
    through."""
    pixels = width * height
    ceiling = 2 * (Image.MAX_IMAGE_PIXELS or pixels)  # None: Pillow has no ceiling
    size = f"{name}: {width}x{height} px is {pixels / 1e6:.1f} megapixels, more than the"
    if pixels > ceiling:
        return ImageTooLarge(f"{size} {ceiling / 1e6:.0f} that can be read at any --max-megapixels; downscale it")
    return ImageTooLarge(f"{size} limit of {max_pixels / 1e6:g}; downscale it, or raise --max-megapixels")


def _claimed_size(data: bytes, name: str) -> tuple[int, int]:
    """The size (px) the header of image `data` claims, where Image.open refused it past Pillow's ceiling without
    saying it: read by the first format that accepts its first bytes, as Image.open reads it, without the ceiling."""
    Image.init()
    for factory, accept in (Image.OPEN[f] for f in Image.ID):
        accepted = accept is None or accept(data[:16])
        if accepted and not isinstance(accepted, str):  # a str is Pillow's warning that it cannot read this kind
            try:
                with factory(io.BytesIO(data), name) as image:
                    return image.size
            except (SyntaxError, IndexError, TypeError, struct.error):  # not this format, as Image.open takes it
                continue
    raise unreadable(data, name)


def jpeg_structure(data: bytes) -> tuple[str | None, tuple[int, bytes], list[int]]:
    """(why JPEG `data` is damaged, read from its marker structure, or None when that is sound; its
    start of frame marker and that segment's payload, (0, b"") when none was read; where each of
    its scans' entropy-coded data ends, at the marker after it, as far as read).

    libjpeg, which OpenCV decodes with, carries on through corrupt image data, drawing the rest of
    the picture grey or garbled, and says so only on stderr: OpenCV gives no way to hear it. So the
    structure is checked instead, from the start of image to its end (what follows, e.g. a phone's
    second picture, is not read): each segment begins with a marker, and a scan's entropy-coded
    data holds 0xFF only before a stuffed 0x00 or the next restart marker in turn, until a marker
    that may follow a scan. Damage that writes a 0xFF or overwrites a stuffed 0x00 or a restart
    marker breaks this (large damage nearly always does); damage that does neither cannot be seen
    without decoding. Stray bytes between the segments before the first scan are skipped, as
    libjpeg skips them: the picture is whole. At the end of the image its scans must have coded the
    whole picture (`_unfinished`). Takes about 0.3 ms per MB: 1.6 ms for a 4.7 MB
    12-megapixel photo, which OpenCV decodes in 85 ms.
    """
    pos, restart_interval, frame = 2, 0, (0, b"")
    scans: list[bytes] = []
    ends: list[int] = []
    while True:
        found = _MARKER.search(data, pos)
        if found is None:
            return _cut_short(bool(scans)), frame, ends
        start, marker = found.start(), found.group(1)[0]
        # After the first scan each segment begins where the one before ends (fill 0xFFs aside):
        # landing elsewhere, the last segment's length was damaged or a false marker was read.
        if scans and data.count(b"\xff", pos, start) != start - pos:
            return f"its data is corrupt (seen at byte {pos}){_GARBLED}", frame, ends
        if marker == 0xD9:
            return _unfinished(*frame, scans) if frame[0] else None, frame, ends
        if marker in _STANDALONE or (scans and marker not in _AFTER_SCAN):
            return f"its data is corrupt (seen at byte {start}){_GARBLED}", frame, ends
        marker_end = found.end()
        if marker_end + 2 > len(data):
            return _cut_short(bool(scans)), frame, ends
        (length,) = struct.unpack_from(">H", data, marker_end)
        pos = marker_end + length
        if marker in _SOF:
            frame = marker, data[marker_end + 2:pos]
        if marker == 0xDD and length >= 4:  # DRI: restart markers come every that many MCUs (0: none)
            (restart_interval,) = struct.unpack_from(">H", data, marker_end + 2)
        if marker == 0xDA:
            scans.append(data[marker_end + 2:pos])
            pos, damage = _scan_end(data, pos, restart_interval)
            if damage:
                return damage, frame, ends
            ends.append(pos)


def _unfinished(sof: int, frame: bytes, scans: list[bytes]) -> str | None:
    """Why the scans of a JPEG (the payloads of its SOS segments) leave its picture unfinished, or None:
    `sof` is its start of frame marker and `frame` that segment's payload.

    Cut short at the end of a scan (or anywhere in a scan but the last), with an end-of-image marker
    added or zeros written over the rest, a JPEG's structure is sound and libjpeg decodes the scans
    it has without a word. A sequential JPEG codes each component whole; a progressive one codes the
    coefficients of each component in bands (Ss..Se of 0..63) from their top bits down to the last
    (Al = 0), and without its last scans the picture comes out blurred or coarse (PSNR 26 dB at 15 %
    of a photo, 41 dB at 60 %), not grey. The standard lets a progressive file stop short on purpose,
    but no encoder's script does (libjpeg's, which Pillow and OpenCV use, for colour, gray and CMYK;
    mozjpeg's, which splits bands its own way): stopping short, it was cut.
    """
    components = frame[6:6 + 3 * frame[5]:3] if len(frame) > 5 else b""
    coded = dict.fromkeys(components, 0)  # component id -> coefficients coded to their last bit
    for scan in scans:
        n = scan[0] if scan else 0
        if len(scan) < 4 + 2 * n:  # too short to name its components and band: libjpeg refuses it
            continue
        first, last, approximation = scan[1 + 2 * n:4 + 2 * n]
        if sof not in _PROGRESSIVE:
            band = _ALL_COEFFICIENTS  # a sequential scan codes its components whole
        elif first <= last and approximation & 15 == 0:  # Al, the bit it codes down to, is the last
            band = (1 << last + 1) - (1 << first)
        else:
            band = 0
        for component in scan[1:1 + 2 * n:2]:
            if component in coded:
                coded[component] |= band
    if all(done & _ALL_COEFFICIENTS == _ALL_COEFFICIENTS for done in coded.values()):
        return None
    return "its scans stop before its picture is complete: cut short, or the rest overwritten"


def _cut_short(scanned: bool) -> str:
    """Why a JPEG that ends before its end-of-image marker is damaged, `scanned` once image data was read."""
    return f"it ends {'before its end-of-image marker' if scanned else 'inside its header'}: cut short"


def _scan_end(data: bytes, pos: int, restart_interval: int) -> tuple[int, str | None]:
    """(where the marker ending the entropy-coded data that begins at `pos` begins, None), or
    (-1, why the data is damaged): a restart marker out of order (any at all when
    `restart_interval` is 0), or no marker after it."""
    for n, found in enumerate(_MARKER.finditer(data, pos)):
        code = found.group(1)[0]
        if not 0xD0 <= code <= 0xD7:
            return found.start(), None
        if not restart_interval or code != 0xD0 + n % 8:
            return -1, f"its image data is corrupt (seen at byte {found.start()}){_GARBLED}"
    return -1, "it ends inside its image data: cut short"


def missing_data(data: bytes, image: np.ndarray, frame: tuple[int, bytes], scan_ends: list[int]) -> str | None:
    """Why JPEG `data`, decoded as `image` ((H, W, 3) BGR with its pixels as stored), is unusable
    for the image data libjpeg ran out of, or None; `frame` (its start of frame marker and payload)
    and `scan_ends` (where its scans' entropy-coded data ends) as `jpeg_structure` read them.

    Zeros written over image data (a card or copy failing), which make no marker, leave the marker
    structure sound, and so does a cut with an end-of-image marker added; libjpeg decodes as far as
    the data goes and says so only on stderr. Decoded again with filler after each scan's data, a
    JPEG whose data ran short has the filler drawn where data was missing; one whose data did not
    is the same to the last pixel, as libjpeg decodes every MCU of a scan before the filler. That
    costs a second decode, made only where data may have run out. A sequential JPEG's MCUs come in
    raster order, and once the data runs out libjpeg draws every one left flat grey 128, to the
    last: it is decoded again when its picture ends in a run of flat grey MCUs (`_flat_end`), be
    the grey missing data or its own (a letterbox, a render's background, a last block of 128). A
    progressive JPEG's later scans refine what its first drew, and one that runs short leaves no
    grey: it is decoded again always (170 ms more for a 12 MP photo, which decodes in 170 ms
    progressive, 90 ms baseline). An arithmetic-coded JPEG (neither Pillow nor OpenCV writes one) cannot
    be decoded again so (`_HUFFMAN`): it is read as it decodes. Of 3754 sound JPEGs on disk
    (scenes, real photos, chessboard renders, grey borders and bands in 11 encodings) and 518 of
    them saved progressive none is refused; the rule before, which took grey for the picture's own
    only where it began the picture or reached up from the run, refused 24 (a last block of 128, a
    grey band at the bottom, a letterbox thinner at the top than an MCU, a blank picture). Of
    damaged copies (zeroed, overwritten, cut with an end marker added, bytes flipped) it refuses
    the 2813 of 3108 of those 518 that rule did, 611 of 972 of the 162 with grey 128 of their own
    (that rule 215), and 1088 of 3108 of the 518 saved progressive (1085 more for their structure).
    """
    sof, payload = frame
    if sof not in _HUFFMAN:
        return None
    share = _flat_end(image, jpeg_mcu(payload))
    if not share and sof not in _PROGRESSIVE:
        return None
    bounds = [0, *scan_ends, len(data)]
    probe = _FILLER.join(data[begin:end] for begin, end in zip(bounds, bounds[1:]))
    probed = _decode_as_stored(np.frombuffer(probe, np.uint8), False)
    if probed is not None and np.array_equal(probed, image):
        return None
    if not share:
        return ("damaged or truncated JPEG file (its image data runs out inside a scan: decoded, part of the picture "
                "is blurred or garbled); copy or export it again")
    percent = np.format_float_positional(100 * share, precision=2, fractional=False, trim="-")  # 100, not 1e+02
    return (f"damaged JPEG file (its image data runs out before its end, and the last {percent} % of its picture is "
            "drawn flat grey (128), as libjpeg draws missing data); copy or export it again")


def _flat_end(image: np.ndarray, mcu: tuple[int, int]) -> float:
    """The share of the MCUs of a decoded JPEG `image` (H, W, 3), in the raster order libjpeg
    decodes them, in the run of flat grey 128 that ends it: 0 when its last MCU is not flat.
    `mcu`: their (height, width) px (`jpeg_mcu`). Each is checked but for its first row and column,
    which chroma upsampling blends with the MCUs above and left."""
    mh, mw = mcu
    h, w = image.shape[:2]
    rows, cols = -(-h // mh), -(-w // mw)
    ys, xs = np.arange(rows * mh), np.arange(cols * mw)
    # An MCU's first row and column are left out unless they are all of it in the image; past the edge, nothing.
    skip_y = ((ys % mh == 0) & (ys + 1 < h)) | (ys >= h)
    skip_x = ((xs % mw == 0) & (xs + 1 < w)) | (xs >= w)
    flat = np.zeros((rows * mh, cols * mw), bool)
    flat[:h, :w] = (image == 128).all(axis=2)
    flat |= skip_y[:, None] | skip_x[None, :]
    blocks = flat.reshape(rows, mh, cols, mw).all(axis=(1, 3)).ravel()
    not_flat = np.flatnonzero(~blocks)
    return (blocks.size - (not_flat[-1] + 1 if not_flat.size else 0)) / blocks.size


def jpeg_mcu(frame: bytes) -> tuple[int, int]:
    """(height, width) px of the MCU, the unit a JPEG is decoded in, from its frame header's payload
    (`jpeg_structure`): 8 x 8 for one component (gray), else 8 times the largest vertical and horizontal
    sampling factors (16 x 16 for the usual 4:2:0). 8 x 8 when the header says nothing usable."""
    factors = frame[7:6 + 3 * frame[5]:3] if len(frame) > 5 and frame[5] > 1 else b""
    if factors:  # per component: its id, then H in the high and V in the low nibble, then its table
        return 8 * max(f & 15 for f in factors), 8 * max(f >> 4 for f in factors)
    return 8, 8


def transparent(data: bytes) -> bool:
    """Whether encoded image `data` says it has transparency: a PNG with an alpha channel or a
    transparent palette entry (tRNS), or a WebP with alpha."""
    kind = image_format(data)
    if kind == "PNG":  # the colour type in IHDR, the first chunk: 4 gray + alpha, 6 RGBA
        return data[25:26] in (b"\x04", b"\x06") or b"tRNS" in data[:max(0, data.find(b"IDAT"))]
    if kind == "WebP":
        if data[12:16] == b"VP8X":  # extended format: flags byte, alpha bit
            return bool(data[20] & 0x10)
        if data[12:16] == b"VP8L":  # lossless: 14-bit width - 1, 14-bit height - 1, then alpha_is_used
            return bool(int.from_bytes(data[21:25], "little") >> 28 & 1)
    return False


# TIFF field type -> (struct code, size in bytes) for the numeric types of the EXIF tags signpose
# reads (13 is an IFD offset, stored like a LONG).
_TYPES = {3: ("H", 2), 4: ("I", 4), 5: ("II", 8), 13: ("I", 4)}
_TAG_ORIENTATION = 0x0112


def exif_tiff(data: bytes) -> bytes | None:
    """The TIFF block of encoded image `data`'s EXIF: a JPEG's APP1 "Exif" segment, a PNG's eXIf
    chunk or a WebP's EXIF chunk; None for another format, or no EXIF. Some writers begin a PNG's
    or WebP's with the "Exif\\0\\0" a JPEG's has: it is dropped."""
    if data[:2] == b"\xff\xd8":
        return _jpeg_exif(data)
    reader = {"PNG": _png_exif, "WebP": _webp_exif}.get(image_format(data) or "")

    tiff = reader(data) if reader else None
    return tiff.removeprefix(b"Exif\x00\x00") if tiff is not None else None


def _png_exif(png: bytes) -> bytes | None:
    """The data of a PNG's eXIf chunk, or None. Chunks: a 4-byte big-endian length, a 4-byte type,
    the data, a 4-byte CRC."""
    pos = 8  # after the signature
    while pos + 8 <= len(png):
        length, kind = struct.unpack_from(">I4s", png, pos)
        if kind == b"eXIf":
            return png[pos + 8:pos + 8 + length]
        if kind == b"IEND":
            return None
        pos += 12 + length
    return None


def _webp_exif(webp: bytes) -> bytes | None:
    """The data of a WebP's EXIF chunk, or None. After the 12-byte RIFF header, chunks: a FourCC, a
    4-byte little-endian size, the data, padded to an even size."""
    pos = 12
    while pos + 8 <= len(webp):
        kind, size = struct.unpack_from("<4sI", webp, pos)
        if kind == b"EXIF":
            return webp[pos + 8:pos + 8 + size]
        pos += 8 + size + (size & 1)
    return None


def _jpeg_segments(jpeg: bytes) -> Iterator[tuple[int, bytes]]:
    """(marker, payload) of each segment of a JPEG's header, up to its first scan (or end)."""
    pos = 2
    while pos + 4 <= len(jpeg):
        if jpeg[pos] != 0xFF:
            return
        marker = jpeg[pos + 1]
        if marker == 0xFF:  # fill byte before a marker
            pos += 1
            continue
        if marker == 0xDA or marker == 0xD9:  # image data or end: the header comes before these
            return
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:  # markers without a length
            pos += 2
            continue
        (length,) = struct.unpack(">H", jpeg[pos + 2:pos + 4])
        yield marker, jpeg[pos + 4:pos + 2 + length]
        pos += 2 + length


def _jpeg_exif(jpeg: bytes) -> bytes | None:
    """The TIFF block inside a JPEG's APP1 "Exif" segment, or None."""
    return next((payload[6:] for marker, payload in _jpeg_segments(jpeg)
                 if marker == 0xE1 and payload.startswith(b"Exif\x00\x00")), None)


def tiff_ifd(tiff: bytes, offset: int, order: str) -> dict[int, float]:
    """Tag -> first value of each numeric entry of the IFD at `offset` (a RATIONAL as num / den).

    Only the first value is read: every tag signpose reads holds one, and a corrupt count must not
    make us allocate or read gigabytes.
    """
    (count,) = struct.unpack_from(order + "H", tiff, offset)
    entries = {}
    for i in range(count):
        tag, kind, n, inline = struct.unpack_from(order + "HHI4s", tiff, offset + 2 + 12 * i)
        if kind not in _TYPES or n == 0:
            continue
        code, size = _TYPES[kind]
        data = inline if size * n <= 4 else tiff[struct.unpack(order + "I", inline)[0]:]
        value = struct.unpack_from(order + code, data)
        if kind != 5:
            entries[tag] = float(value[0])
        elif value[1]:
            entries[tag] = value[0] / value[1]
    return entries


def exif_orientation(data: bytes) -> int:
    """The EXIF orientation of encoded image `data`, 1-8: how its pixels as stored are turned to be
    shown (1: as stored; 3: a half turn; 6 and 8: a quarter turn clockwise and anticlockwise; 2, 4,
    5, 7: those mirrored), from its EXIF (`exif_tiff`) or, for a TIFF, its first IFD. 1 when it
    has none, or a value out of range (as decoders read it)."""
    tiff = data if image_format(data) == "TIFF" else exif_tiff(data)
    if tiff is None or tiff[:4] not in (b"II*\x00", b"MM\x00*"):
        return 1
    order = "<" if tiff[:2] == b"II" else ">"
    try:
        value = tiff_ifd(tiff, struct.unpack_from(order + "I", tiff, 4)[0], order).get(_TAG_ORIENTATION, 1.0)
    except struct.error:  # offsets pointing outside the block: truncated or corrupt EXIF
        return 1
    return int(value) if value in ORIENTATIONS else 1


def resize_map(fx: float, fy: float) -> np.ndarray:
    """(3, 3) map of px in an image to px in it resized `fx` times across and `fy` times down by
    cv2.resize, which keeps pixel centres at whole px: u -> (u + 0.5) f - 0.5."""
    return np.array([[fx, 0, 0.5 * fx - 0.5], [0, fy, 0.5 * fy - 0.5], [0, 0, 1]])


def to_8bit(image: np.ndarray) -> np.ndarray:
    """A uint8 or uint16 image -> uint8, 16 bits shifted down by as many bits as its largest value
    has beyond 8: 10- and 12-bit camera data stored in 16 bits (values up to 1023 or 4095) keeps
    its levels, which the top 8 of 16 bits (OpenCV's scaling) left at 0-3 and 0-15."""
    if image.dtype != np.uint16:
        return image
    return (image >> max(0, int(image.max()).bit_length() - 8)).astype(np.uint8)


def on_white(image: np.ndarray) -> np.ndarray:
    """(H, W, 4) BGRA, 8- or 16-bit -> (H, W, 3) uint8 BGR over white, as a page shows it (a sign's
    artwork drawn on a transparent ground is a sign on white)."""
    opacity = image[..., 3:].astype(np.float32) / np.iinfo(image.dtype).max
    return np.round(to_8bit(image[..., :3]) * opacity + 255 * (1 - opacity)).astype(np.uint8)


def decode_image(data: bytes, name: str = "image", as_stored: bool = False) -> np.ndarray:
    """Encoded bytes (JPEG, PNG, TIFF, WebP, BMP, GIF first frame, ...) -> (H, W, 3) uint8 BGR.

    Turned as its EXIF orientation says (`exif_orientation`), as it is shown; with `as_stored`,
    its pixels as the camera stored them, which is what a camera file describes. 16-bit images
    are scaled to 8 bits (`to_8bit`), transparent pixels (PNG, WebP) shown over white, gray
    expanded. A JPEG whose data is damaged is refused (`jpeg_structure`, `missing_data`), as one that
    cannot be decoded is.
    """
    if not data:
        raise ImageError(f"{name}: file is empty")
    kind = image_format(data)
    # Before decoding: libjpeg would decode damage as grey or garbled pixels, warning only on stderr.
    damage, frame, scan_ends = jpeg_structure(data) if kind == "JPEG" else (None, (0, b""), [])
    if damage:
        raise ImageError(f"{name}: damaged or truncated JPEG file ({damage}); copy or export it again")
    try:
        image = _decode_as_stored(np.frombuffer(data, dtype=np.uint8), transparent(data))
    except cv2.error as exc:
        raise ImageError(f"{name}: cannot decode image: {exc.err or exc}") from None
    if image is None or image.dtype not in (np.uint8, np.uint16):
        raise unreadable(data, name)
    # As stored: libjpeg fills missing data in the order it decodes, before any EXIF orientation turns it.
    missing = missing_data(data, image, frame, scan_ends) if kind == "JPEG" else None
    if missing:
        raise ImageError(f"{name}: {missing}")
    image, orientation = to_8bit(image), exif_orientation(data)
    if kind == "TIFF":  # libtiff turns it as its orientation says, whatever OpenCV is asked
        return turned(image, orientation, undo=True) if as_stored else image
    return image if as_stored else turned(image, orientation)


def decoders_kept_quiet() -> AbstractContextManager[None]:
    """A context in which what the decoders print on stderr (_DECODER_CHATTER) is kept off it (`_StderrCapture`):
    around a decode whose failure signpose says in its own words."""
    return _STDERR_CAPTURE.capturing()


def _imdecode(buf: np.ndarray, flags: int) -> np.ndarray | None:
    """cv2.imdecode, its decoders kept quiet (`decoders_kept_quiet`)."""
    with decoders_kept_quiet():
        return cv2.imdecode(buf, flags)


def _decode_as_stored(buf: np.ndarray, with_alpha: bool) -> np.ndarray | None:
    """Encoded image `buf` (uint8) decoded as (H, W, 3) BGR of 8 or 16 bits, its pixels as stored
    (a TIFF's excepted, see decode_image), `with_alpha` shown over white; None when OpenCV cannot.

    Turned by the caller, not by OpenCV: which formats OpenCV turns depends on its version and the
    mode read (never with alpha), and the camera must be turned as the pixels were.
    """
    if with_alpha:
        image = _imdecode(buf, cv2.IMREAD_UNCHANGED)
        if image is not None and image.ndim == 3 and image.shape[2] == 4:
            return on_white(image)
    # ANYDEPTH: 16 bits as they are, for to_8bit (IMREAD_COLOR keeps their top 8)
    return _imdecode(buf, cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH | cv2.IMREAD_IGNORE_ORIENTATION)


def turned(image: np.ndarray, orientation: int, undo: bool = False) -> np.ndarray:
    """`image` (H, W[, C]) as stored, turned as EXIF `orientation` (1-8, `exif_orientation`) says to
    be shown; with `undo`, `image` as shown turned back to as stored."""
    if undo:
        orientation = {6: 8, 8: 6}.get(orientation, orientation)  # the others undo themselves
    turn = _TURNS.get(orientation)
    return turn(image) if turn else image


def read_file(path: str | Path) -> bytes:
    """The bytes of an image file, with `ImageError` for what a user can fix (missing, not a file, no access).

    What is not a regular file is refused from its `stat`, never opened: reading a named pipe waits
    for a writer, forever when there is none, and a device may never end.
    """
    path = Path(path)
    try:
        mode = path.stat().st_mode
        if not stat.S_ISREG(mode):
            raise ImageError(f"{path}: is {_NOT_FILES.get(stat.S_IFMT(mode), 'a special file')}, not a regular file")
        return path.read_bytes()
    except FileNotFoundError:
        raise ImageError(f"{path}: no such file") from None
    except PermissionError:
        raise ImageError(f"{path}: permission denied") from None
    except OSError as exc:  # a path through a file (NotADirectoryError), a link to itself, ...
        raise ImageError(f"{path}: {exc.strerror or exc}") from None


def read_image(path: str | Path) -> np.ndarray:
    """Read an image file from disk as (H, W, 3) uint8 BGR."""
    return decode_image(read_file(path), str(path))


def inside_image(x: np.ndarray, y: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Where the points (x, y) px (arrays of one shape) lie in an image of `shape` (H, W[, C]), from
    the first pixel's centre to the last's: what a bilinear read sees without a border. Bool, shaped as x."""
    h, w = shape[:2]
    return (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) BGR or (H, W) gray -> (H, W) uint8 gray."""
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
