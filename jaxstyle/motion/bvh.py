"""Reading and writing BVH motion capture files.

The reader accepts any hierarchy: several roots, ``End Site`` blocks, any number of channels per
joint (position channels on any joint, one to three rotation channels in any order), names with
spaces, and braces on their own lines or not. Rotations become quaternions (see
:mod:`jaxstyle.motion.quat` for the conventions: the listed rotation channels are intrinsic, so
``Zrotation Yrotation Xrotation`` means ``Rz @ Ry @ Rx``).

The motion block is parsed by pandas' C tokenizer (about 2.5x faster than ``np.loadtxt`` on the
same text); when that fast path finds anything unusual, a line-by-line pass locates the problem,
so every error names the file and line.

What the reader accepts and refuses (see also ``docs/bad_input.md``):

* a UTF-8 byte order mark at the start is skipped; CRLF (and lone CR) line endings, tabs and any
  runs of spaces parse exactly like plain ``\n`` and single spaces;
* a motion row with the wrong number of values fails fast (bounded time and memory, whatever the
  row's length) with the row's line;
* NaN, inf, and absurd finite numbers are refused: every OFFSET and motion value must satisfy
  ``|value| <= 1e7`` (:data:`MAX_ABS_VALUE`; 1e7 cm is 100 km, 1e7 degrees about 28,000 turns),
  and ``Frame Time`` must lie in ``[0.001, 1]`` seconds (1-1000 frames/s, :data:`MIN_FPS`,
  :data:`MAX_FPS`): a clip at 1 frame per 10 s resampled to 60 frames/s would be 600 times longer;
* every problem raises :class:`~jaxstyle.errors.MotionDataError` (a ``ValueError`` and a
  :class:`~jaxstyle.errors.JaxstyleError`) whose message starts with ``<file>, line <n>: ``.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import stat
from pathlib import Path

import numpy as np

from jaxstyle.errors import MotionDataError
from jaxstyle.motion import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, quat

_KNOWN_CHANNELS = POSITION_CHANNELS + ROTATION_CHANNELS
_EULER_BLOCK = 256  # frames converted from Euler angles at a time
_FPS_SNAP = 1e-3  # fps within this (relative) of an integer is snapped to it: 1/0.016667 -> 60.
MAX_ABS_VALUE = 1e7  # largest |value| accepted in OFFSET and motion rows
MAX_BVH_MB = 200.0  # the default size limit of read_bvh (JAXSTYLE_MAX_BVH_MB changes it)
MIN_FPS, MAX_FPS = 1.0, 1000.0  # the frame rates accepted (Frame Time 1 s to 1 ms); capture runs at 24-480
_BOM = b"\xef\xbb\xbf"
_WIDE_ROW = 3000  # channels per row above which the motion block is parsed by numpy instead of pandas


def _check_frame_time(frame_time: float, source, lineno: int) -> None:
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise MotionDataError(f"Frame Time must be a positive number, got {frame_time}", source, lineno)
    if not 1.0 / MAX_FPS <= frame_time <= 1.0 / MIN_FPS:
        raise MotionDataError(
            f"Frame Time {frame_time:g} s ({1.0 / frame_time:.4g} frames/s) is outside the sane range "
            f"[{1.0 / MAX_FPS:g}, {1.0 / MIN_FPS:g}] seconds ({MIN_FPS:g}-{MAX_FPS:g} frames/s)", source, lineno)


def _fps_from_frame_time(frame_time: float) -> float:
    fps = 1.0 / frame_time
    nearest = round(fps)
    return float(nearest) if nearest > 0 and abs(fps - nearest) <= _FPS_SNAP * nearest else fps


def frame_rate(path: str | os.PathLike) -> float:
    """A BVH file's frames per second from its ``Frame Time:`` line, as :func:`read_bvh` gives it
    (snapped like there), without reading the frames."""
    with _open_regular(Path(path)) as f:
        for lineno, line in enumerate(f, 1):
            if line.strip().lower().startswith(b"frame time:"):
                try:
                    frame_time = float(line.split(b":", 1)[1])
                except ValueError:
                    raise MotionDataError(f"cannot read the frame time from {line.strip()!r}", path, lineno) from None
                _check_frame_time(frame_time, path, lineno)
                return _fps_from_frame_time(frame_time)
    raise MotionDataError("no 'Frame Time:' line", path)


def read_joint_names(path: str | os.PathLike) -> tuple[str, ...]:
    """The joint names of a BVH file's hierarchy, read without its motion block (a header of at
    most :func:`max_bvh_bytes` is read)."""
    path = Path(path)
    limit, got, lines = max_bvh_bytes(), 0, []
    with _open_regular(path) as f:
        for raw in f:
            got += len(raw)
            if got > limit:
                raise MotionDataError(_too_big(got, limit), path)
            line = raw.decode("utf-8", errors="replace").rstrip("\r\n").lstrip("\ufeff")
            if line.strip() == "MOTION":
                return _parse_hierarchy(lines, str(path))["names"]
            lines.append(line)
    raise MotionDataError("missing MOTION section after the hierarchy", path, len(lines))


def read_bvh_names(path: str | os.PathLike) -> tuple[str, ...]:
    """The joint names of the BVH file at ``path``, the whole file read and checked as
    :func:`read_bvh` does (a malformed motion block is refused with its line). A small result to
    return from a reader process (``jaxstyle.play.learn.ClipReader``), and this module imports no
    JAX, so such a process starts in a fraction of a second."""
    return tuple(read_bvh(path).names)


def read_bvh(path: str | os.PathLike, *, max_bytes: int | None = None) -> Motion:
    """Reads a BVH file into a :class:`~jaxstyle.motion.Motion`.

    ``fps`` is ``1 / Frame Time``, snapped to the nearest integer when within 0.1% of it
    (files store ``0.016667`` for 60 fps).

    A leading UTF-8 byte order mark, CRLF line endings and tabs are accepted.

    ``max_bytes``: the largest file read (default :func:`max_bvh_bytes`); pipes, sockets and
    devices are refused without reading (a FIFO would block, ``/dev/zero`` never ends).

    Raises:
      MotionDataError: the file is missing, not a regular file, too large, empty or malformed
        (e.g. a motion row with the wrong number of values, however long), or holds NaN/inf or an
        absurd value (``|value| > 1e7``, :data:`MAX_ABS_VALUE`, in an OFFSET or a motion row); the
        message names the file and the line.
    """
    path = Path(path)
    limit = max_bytes if max_bytes is not None else max_bvh_bytes()
    f = _open_regular(path)
    size = os.fstat(f.fileno()).st_size
    if size > limit:
        f.close()
        raise MotionDataError(_too_big(size, limit), path)
    with f:
        try:
            # read(limit + 1) would allocate the whole limit at once; pieces of the expected size do not
            pieces, got = [], 0
            while got <= limit:
                piece = f.read(min(limit + 1 - got, max(size + 1, 1 << 16)))
                if not piece:
                    break
                pieces.append(piece)
                got += len(piece)
            text = b"".join(pieces)
        except OSError as e:
            raise MotionDataError(f"cannot read file ({e.strerror})", path) from None
    if len(text) > limit:  # grew while being read
        raise MotionDataError(_too_big(len(text), limit), path)
    return parse_bvh(text, source=str(path))


def _open_regular(path: Path):
    """``path`` opened for reading in binary, or a MotionDataError: missing, a directory, or not a
    regular file (opened with O_NONBLOCK, so a FIFO without a writer does not block)."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise MotionDataError("file not found", path) from None
    except IsADirectoryError:
        raise MotionDataError("is a directory, not a BVH file", path) from None
    except OSError as e:
        raise MotionDataError(f"cannot read file ({e.strerror})", path) from None
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        if stat.S_ISDIR(mode):
            raise MotionDataError("is a directory, not a BVH file", path)
        raise MotionDataError("is not a regular file (a pipe, socket or device); give a BVH file", path)
    return os.fdopen(fd, "rb")


def max_bvh_bytes() -> int:
    """The largest BVH file :func:`read_bvh` reads: ``JAXSTYLE_MAX_BVH_MB`` megabytes (default
    :data:`MAX_BVH_MB`; the largest 100STYLE file is 4 MB)."""
    raw = os.environ.get("JAXSTYLE_MAX_BVH_MB", "")
    try:
        mb = float(raw) if raw.strip() else MAX_BVH_MB
    except ValueError:
        mb = float("nan")
    if not (math.isfinite(mb) and mb > 0):
        raise MotionDataError(f"JAXSTYLE_MAX_BVH_MB must be a positive number of megabytes, got {raw!r}")
    return int(mb * 1e6)


def _too_big(size: int, limit: int) -> str:
    return (f"is {size / 1e6:.1f} MB, more than the {limit / 1e6:g} MB a BVH file may have here "
            "(set JAXSTYLE_MAX_BVH_MB to read larger files)")


def parse_bvh(text: str | bytes, source: str = "<string>") -> Motion:
    """Parses BVH text or bytes (see :func:`read_bvh`); ``source`` names it in error messages."""
    data = text.encode("utf-8", errors="replace") if isinstance(text, str) else bytes(text)
    if data.startswith(_BOM):
        data = data[len(_BOM):]
    if b"\r" in data:  # CRLF (or old Mac CR) line endings: normalise; line numbers are unchanged for CRLF
        data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    if not data or data.isspace():
        raise MotionDataError("empty file", source, 1)
    match = re.search(rb"^[ \t]*MOTION[ \t]*$", data, flags=re.MULTILINE)
    if match is None:
        n_lines = data.count(b"\n") + 1
        if re.search(rb"^\s*HIERARCHY\b", data) is None:
            raise MotionDataError("missing HIERARCHY section (the file must start with HIERARCHY)", source, 1)
        raise MotionDataError("missing MOTION section after the hierarchy", source, n_lines)
    header_lines = _decode(data[: match.start()]).split("\n")
    skeleton = _parse_hierarchy(header_lines, source)
    motion_line = len(header_lines)  # 1-based line number of "MOTION"
    # The Frames/Frame Time lines are short: decode a small window after MOTION for them.
    after = match.end() + (1 if data[match.end():match.end() + 1] == b"\n" else 0)
    # surrogateescape round-trips every byte, so the consumed characters map back to exact byte counts.
    window = data[after:after + 4096].decode("utf-8", errors="surrogateescape")
    n_frames, frame_time, consumed, block_first_line = _parse_motion_header(window, motion_line + 1, source)
    rest = data[after + len(window[:consumed].encode("utf-8", errors="surrogateescape")):]
    n_channels = sum(len(c) for c in skeleton["channels"])
    values = _parse_motion_block(rest, n_frames, n_channels, block_first_line, source)
    return _build_motion(skeleton, values, _fps_from_frame_time(frame_time), source)


def _parse_hierarchy(lines: list[str], source: str) -> dict:
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    end_parents: list[int] = []
    end_offsets: list[list[float]] = []
    seen: set[str] = set()  # the names so far (a set: the duplicate check stays linear in the joint count)
    stack: list[int] = []  # open blocks: joint index, or -2 for an End Site
    pending: int | None = None  # a ROOT/JOINT/End Site line waiting for its "{"
    saw_header = False
    for lineno, raw in enumerate(lines, start=1):
        tokens = raw.replace("{", " { ").replace("}", " } ").split()
        if not tokens:
            continue
        if not saw_header:
            if tokens[0] != "HIERARCHY":
                raise MotionDataError(f"expected HIERARCHY, found {raw.strip()[:40]!r}", source, lineno)
            saw_header = True
            tokens = tokens[1:]
        i = 0
        while i < len(tokens):
            tok = tokens[i]
            if tok in ("ROOT", "JOINT"):
                # The name runs to the end of the line or to a "{" (names may contain spaces).
                end = tokens.index("{", i + 1) if "{" in tokens[i + 1:] else len(tokens)
                name = " ".join(tokens[i + 1:end])
                if not name:
                    raise MotionDataError(f"{tok} without a name", source, lineno)
                if tok == "JOINT" and (not stack or stack[-1] < 0):
                    raise MotionDataError(f"JOINT {name!r} outside a joint block", source, lineno)
                if tok == "ROOT" and stack:
                    raise MotionDataError(f"ROOT {name!r} inside another joint", source, lineno)
                if name in seen:
                    raise MotionDataError(f"duplicate joint name {name!r}", source, lineno)
                seen.add(name)
                names.append(name)
                parents.append(stack[-1] if stack else -1)
                offsets.append([0.0, 0.0, 0.0])
                channels.append(())
                pending = len(names) - 1
                i = end
                continue
            if tok == "End":
                if i + 1 >= len(tokens) or tokens[i + 1] != "Site":
                    raise MotionDataError("expected 'End Site'", source, lineno)
                if not stack or stack[-1] < 0:
                    raise MotionDataError("End Site outside a joint block", source, lineno)
                end_parents.append(stack[-1])
                end_offsets.append([0.0, 0.0, 0.0])
                pending = -2
                i += 2
                continue
            if tok == "{":
                if pending is None:
                    raise MotionDataError("'{' without a ROOT, JOINT or End Site before it", source, lineno)
                stack.append(pending)
                pending = None
                i += 1
                continue
            if tok == "}":
                if not stack:
                    raise MotionDataError("unbalanced '}'", source, lineno)
                stack.pop()
                i += 1
                continue
            if tok == "OFFSET":
                vals = _floats(tokens[i + 1:i + 4], 3, "OFFSET", source, lineno)
                if not stack:
                    raise MotionDataError("OFFSET outside a joint block", source, lineno)
                if stack[-1] == -2:  # inside an End Site: it is the latest one
                    end_offsets[-1] = vals
                else:
                    offsets[stack[-1]] = vals
                i += 4
                continue
            if tok == "CHANNELS":
                if not stack or stack[-1] < 0:
                    raise MotionDataError("CHANNELS outside a joint block", source, lineno)
                try:
                    count = int(tokens[i + 1])
                except (IndexError, ValueError):
                    raise MotionDataError("CHANNELS must be followed by a channel count", source, lineno) from None
                chans = tuple(tokens[i + 2:i + 2 + count])
                if len(chans) != count:
                    raise MotionDataError(f"CHANNELS says {count} channels but lists {len(chans)}", source, lineno)
                for c in chans:
                    if c not in _KNOWN_CHANNELS:
                        raise MotionDataError(
                            f"unknown channel name {c!r} (known: {', '.join(_KNOWN_CHANNELS)})", source, lineno)
                if len(set(chans)) != len(chans):
                    raise MotionDataError(f"repeated channel in {' '.join(chans)}", source, lineno)
                channels[stack[-1]] = chans
                i += 2 + count
                continue
            raise MotionDataError(f"unexpected token {tok!r} in the hierarchy", source, lineno)
    if not saw_header:
        raise MotionDataError("missing HIERARCHY section", source, 1)
    if stack or pending is not None:
        raise MotionDataError("hierarchy ends with an unclosed '{' before MOTION", source, len(lines))
    if not names:
        raise MotionDataError("the hierarchy defines no joints", source, 1)
    return dict(names=tuple(names), parents=np.array(parents, dtype=np.int64),
                offsets=np.array(offsets, dtype=np.float64), channels=tuple(channels),
                end_parents=np.array(end_parents, dtype=np.int64),
                end_offsets=np.array(end_offsets, dtype=np.float64).reshape(-1, 3))


def _floats(tokens: list[str], n: int, what: str, source: str, lineno: int) -> list[float]:
    try:
        vals = [float(t) for t in tokens]
    except ValueError:
        raise MotionDataError(f"{what} values must be numbers, got {' '.join(tokens)!r}", source, lineno) from None
    if len(vals) != n:
        raise MotionDataError(f"{what} needs {n} numbers, got {len(vals)}", source, lineno)
    if not all(np.isfinite(vals)):
        raise MotionDataError(f"{what} holds NaN or inf", source, lineno)
    if max(abs(v) for v in vals) > MAX_ABS_VALUE:
        raise MotionDataError(f"{what} holds an absurd value (|value| > {MAX_ABS_VALUE:g}): {' '.join(tokens)}",
                              source, lineno)
    return vals


def _parse_motion_header(rest: str, lineno: int, source: str):
    """Reads the 'Frames:' and 'Frame Time:' lines.

    Returns (frames, frame_time, characters consumed, 1-based line number where the block starts).
    """
    found: dict[str, float] = {}
    pos = 0
    while len(found) < 2:
        if pos >= len(rest):
            missing = "Frames:" if "Frames" not in found else "Frame Time:"
            raise MotionDataError(f"missing '{missing}' line after MOTION", source, lineno)
        end = rest.find("\n", pos)
        end = len(rest) if end < 0 else end
        line = rest[pos:end].strip()
        if line:
            key, sep, value = line.partition(":")
            key = " ".join(key.split())
            expected = "Frames" if not found else "Frame Time"
            if not sep or key != expected:
                expected += ":"
                raise MotionDataError(f"expected '{expected}', found {line[:40]!r}", source, lineno)
            try:
                found[key] = int(value) if key == "Frames" else float(value)
            except ValueError:
                raise MotionDataError(f"{key} must be a number, got {value.strip()!r}", source, lineno) from None
        pos = end + 1
        lineno += 1
    n_frames, frame_time = int(found["Frames"]), float(found["Frame Time"])
    if n_frames < 1:
        raise MotionDataError(f"Frames must be at least 1, got {n_frames}", source, lineno - 2)
    _check_frame_time(frame_time, source, lineno - 1)
    return n_frames, frame_time, pos, lineno


def _decode(data: bytes) -> str:
    return data.decode("utf-8", errors="replace")


def _parse_motion_block(block: bytes, n_frames: int, n_channels: int, first_line: int, source: str) -> np.ndarray:
    """``(n_frames, n_channels)`` values of the motion block, or an error naming the bad line."""
    values = _fast_parse(block, n_frames, n_channels)
    if values is not None:
        return values
    return _careful_parse(_decode(block), n_frames, n_channels, first_line, source)


def _first_row(block: bytes) -> bytes | None:
    """The first non-blank line of the block (without its newline), or None."""
    pos = 0
    while pos < len(block):
        end = block.find(b"\n", pos)
        end = len(block) if end < 0 else end
        line = block[pos:end]
        if line and not line.isspace():
            return line
        pos = end + 1
    return None


def _fast_parse(block: bytes, n_frames: int, n_channels: int) -> np.ndarray | None:
    if n_channels == 0 or n_frames > block.count(b"\n") + 1:  # too few lines for the rows: let the careful pass say
        return None
    first = _first_row(block)
    # pandas takes the column count from the first row and allocates every later row to that
    # width: a first row with millions of values would cost gigabytes before any check. So the
    # first row's width is checked here, with bounded work (split stops after n_channels + 1).
    if first is None or len(first.split(None, n_channels)) != n_channels:
        return None
    # sep=" " is the fast case; it is only safe (and only right) when single spaces separate the values.
    seps = [" "] if b"\t" not in first and first.count(b" ") + 1 == n_channels else []
    seps.append(r"\s+")

    if n_channels > _WIDE_ROW:
        return _wide_parse(block, n_frames, n_channels)

    import pandas as pd  # deferred: importing pandas costs ~0.3 s

    for sep in seps:
        try:
            # dtype is left to inference (faster than forcing float64); a column holding a
            # non-number comes back as strings and fails the conversion below.
            frame = pd.read_csv(io.BytesIO(block), sep=sep, header=None, engine="c", na_filter=False,
                                skip_blank_lines=True, nrows=n_frames + 1, low_memory=False,
                                quoting=csv.QUOTE_NONE)
            values = frame.to_numpy(dtype=np.float64)
        except (ValueError, TypeError, OverflowError, pd.errors.ParserError, pd.errors.EmptyDataError):
            continue
        # The comparison is False for NaN, so this also refuses non-finite values.
        if values.shape == (n_frames, n_channels) and (np.abs(values) <= MAX_ABS_VALUE).all():
            return values
    return None


def _wide_parse(block: bytes, n_frames: int, n_channels: int) -> np.ndarray | None:
    """Rows of many thousand values (skeletons of thousands of joints): pandas builds one column
    object per value there (quadratic in practice: 10,000 joints took seconds), so the rows are
    split and converted by numpy in one pass, linear in the file's size. None when a row's count
    is off or a value is not a finite number within :data:`MAX_ABS_VALUE` (the careful pass then
    names the line)."""
    rows = [line for line in block.split(b"\n") if line and not line.isspace()]
    if len(rows) != n_frames or any(len(row.split()) != n_channels for row in rows):
        return None
    try:
        values = np.array(b" ".join(rows).split(), dtype=np.float64).reshape(n_frames, n_channels)
    except ValueError:
        return None
    return values if (np.abs(values) <= MAX_ABS_VALUE).all() else None


def _careful_parse(block: str, n_frames: int, n_channels: int, first_line: int, source: str) -> np.ndarray:
    rows = []
    last_row_line = first_line
    for lineno, line in enumerate(block.split("\n"), start=first_line):
        tokens = line.split(None, n_channels)  # bounded: a huge row is not split into millions of strings
        if not tokens:
            continue
        last_row_line = lineno
        if len(rows) == n_frames:
            raise MotionDataError(f"more motion rows than 'Frames: {n_frames}'", source, lineno)
        if len(tokens) != n_channels:
            count = len(tokens) if len(tokens) < n_channels else sum(1 for _ in re.finditer(r"\S+", line))
            raise MotionDataError(
                f"motion row {len(rows) + 1} has {count} values; the hierarchy has {n_channels} channels",
                source, lineno)
        try:
            row = np.array([float(t) for t in tokens])
        except ValueError:
            bad = next(t for t in tokens if not _is_float(t))
            raise MotionDataError(f"motion row {len(rows) + 1} holds a non-number {bad!r}", source, lineno) from None
        if not np.isfinite(row).all():
            col = int(np.flatnonzero(~np.isfinite(row))[0])
            raise MotionDataError(f"motion row {len(rows) + 1} holds {tokens[col]} (value {col + 1})", source, lineno)
        if not (np.abs(row) <= MAX_ABS_VALUE).all():
            col = int(np.flatnonzero(np.abs(row) > MAX_ABS_VALUE)[0])
            raise MotionDataError(
                f"motion row {len(rows) + 1} holds an absurd value {tokens[col]} (value {col + 1}; "
                f"|value| must be <= {MAX_ABS_VALUE:g})", source, lineno)
        rows.append(row)
    if len(rows) < n_frames:
        raise MotionDataError(
            f"'Frames: {n_frames}' but the file has only {len(rows)} motion rows", source, last_row_line)
    return np.stack(rows)


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _build_motion(skel: dict, values: np.ndarray, fps: float, source: str) -> Motion:
    n_frames = values.shape[0]
    n_joints = len(skel["names"])
    local_positions = np.broadcast_to(skel["offsets"], (n_frames, n_joints, 3)).copy()
    rotations = np.empty((n_frames, n_joints, 4))
    # Group joints by rotation-channel order so each group is one vectorised conversion.
    groups: dict[str, tuple[list[int], list[list[int]]]] = {}
    col = 0
    for j, chans in enumerate(skel["channels"]):
        rot_cols = []
        order = ""
        for c in chans:
            if c in POSITION_CHANNELS:
                local_positions[:, j, POSITION_CHANNELS.index(c)] = values[:, col]
            else:
                order += c[0].lower()
                rot_cols.append(col)
            col += 1
        joints, cols = groups.setdefault(order, ([], []))
        joints.append(j)
        cols.append(rot_cols)
    for order, (joints, cols) in groups.items():
        if not order:
            rotations[:, joints] = quat.identity()
            continue
        cols = np.array(cols)
        # All joints usually share one order: then a slice lets the conversion write in place
        # (a list of joints would index a copy, so that case is assigned instead).
        contiguous = joints == list(range(joints[0], joints[-1] + 1))
        # Blocks of frames keep the conversion's temporaries in cache (about 2x faster overall).
        for start in range(0, n_frames, _EULER_BLOCK):
            stop = min(start + _EULER_BLOCK, n_frames)
            if contiguous:
                quat.from_euler(values[start:stop, cols], order, degrees=True,
                                out=rotations[start:stop, joints[0]:joints[-1] + 1])
            else:
                rotations[start:stop, joints] = quat.from_euler(values[start:stop, cols], order, degrees=True)
    return Motion(names=skel["names"], parents=skel["parents"], offsets=skel["offsets"], rotations=rotations,
                  local_positions=local_positions, fps=fps, channels=skel["channels"],
                  end_site_parents=skel["end_parents"], end_site_offsets=skel["end_offsets"], source=source)


# --------------------------------------------------------------------------------------------- writing

DEFAULT_ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation")
DEFAULT_JOINT_CHANNELS = ("Zrotation", "Yrotation", "Xrotation")


def motion_channel_values(motion: Motion, channels: tuple[tuple[str, ...], ...] | None = None) -> np.ndarray:
    """``(T, C)`` BVH channel values of a motion (positions in file units, angles in degrees).

    ``channels`` defaults to the motion's own channel lists. A joint's rotation channels must be
    three distinct axes (any order), or none if its rotation is the identity throughout; position
    channels may be any subset of x, y, z (unlisted components must equal the offset).
    """
    channels = motion.channels if channels is None else channels
    cols = []
    for j, chans in enumerate(channels):
        rot = [c for c in chans if c in ROTATION_CHANNELS]
        order = "".join(c[0].lower() for c in rot)
        angles = None
        if rot:
            if len(rot) != 3:
                raise MotionDataError(
                    f"joint {motion.names[j]!r}: cannot write {len(rot)} rotation channels; "
                    "use three (any order)", motion.source)
            angles = quat.to_euler(motion.rotations[:, j], order, degrees=True)
        elif not np.allclose(np.abs(motion.rotations[:, j, 0]), 1.0, atol=1e-6):
            raise MotionDataError(
                f"joint {motion.names[j]!r} rotates but has no rotation channels to write", motion.source)
        unlisted = [k for k, c in enumerate(POSITION_CHANNELS) if c not in chans]
        scale = max(float(np.abs(motion.offsets).max(initial=0.0)), 1.0)
        if unlisted and not np.allclose(motion.local_positions[:, j, unlisted], motion.offsets[j, unlisted],
                                        rtol=0.0, atol=1e-9 * scale):
            missing = " ".join(POSITION_CHANNELS[k] for k in unlisted)
            raise MotionDataError(
                f"joint {motion.names[j]!r} moves along {missing} but has no such channel to write; "
                "pass channels that include it", motion.source)
        for c in chans:
            if c in POSITION_CHANNELS:
                cols.append(motion.local_positions[:, j, POSITION_CHANNELS.index(c)])
            else:
                cols.append(angles[:, order.index(c[0].lower())])
    if not cols:
        return np.zeros((motion.num_frames, 0))
    return np.stack(cols, axis=1)


def default_channels(motion: Motion) -> tuple[tuple[str, ...], ...]:
    """Channel lists for a motion without its own.

    Roots, and any other joint whose translation differs from its offset in some frame, get 6
    channels (``X/Y/Zposition Zrotation Yrotation Xrotation``); other joints get 3 rotations.
    """
    moves = np.any(np.abs(motion.local_positions - motion.offsets) > 0, axis=0).any(axis=-1)
    return tuple(DEFAULT_ROOT_CHANNELS if p < 0 or moves[j] else DEFAULT_JOINT_CHANNELS
                 for j, p in enumerate(motion.parents))


def format_bvh(motion: Motion, channels: tuple[tuple[str, ...], ...] | None = None, precision: int = 6) -> str:
    """BVH text of a motion (see :func:`write_bvh`)."""
    if channels is None:
        channels = motion.channels if any(motion.channels) else default_channels(motion)
    children: dict[int, list[int]] = {}
    for j, p in enumerate(motion.parents):
        children.setdefault(int(p), []).append(j)
    ends: dict[int, list[np.ndarray]] = {}
    for p, off in zip(motion.end_site_parents, motion.end_site_offsets, strict=True):
        ends.setdefault(int(p), []).append(off)
    fmt = f"%.{precision}f"
    out = ["HIERARCHY"]

    def emit(j: int, depth: int):
        pad = "  " * depth
        kind = "ROOT" if motion.parents[j] < 0 else "JOINT"
        out.append(f"{pad}{kind} {motion.names[j]}")
        out.append(pad + "{")
        out.append(f"{pad}  OFFSET " + " ".join(fmt % v for v in motion.offsets[j]))
        if channels[j]:
            out.append(f"{pad}  CHANNELS {len(channels[j])} " + " ".join(channels[j]))
        for c in children.get(j, []):
            emit(c, depth + 1)
        for off in ends.get(j, []):
            out.extend([f"{pad}  End Site", f"{pad}  {{",
                        f"{pad}    OFFSET " + " ".join(fmt % v for v in off), f"{pad}  }}"])
        out.append(pad + "}")

    for root in children.get(-1, []):
        emit(root, 0)
    values = motion_channel_values(motion, channels)
    buf = io.StringIO()
    np.savetxt(buf, values, fmt=fmt, delimiter=" ")
    out += ["MOTION", f"Frames: {motion.num_frames}", f"Frame Time: {1.0 / motion.fps:.6f}"]
    return "\n".join(out) + "\n" + buf.getvalue()


def write_bvh(motion: Motion, path: str | os.PathLike, channels: tuple[tuple[str, ...], ...] | None = None,
              precision: int = 6) -> Path:
    """Writes a motion as BVH, atomically (a temporary file renamed into place).

    Joints are written in the motion's order, which must be depth-first (as read from a BVH file)
    for the file to read back in the same order. ``channels`` defaults to the motion's own channel
    lists, or 6 channels on roots and ``Zrotation Yrotation Xrotation`` elsewhere for a motion
    without any (e.g. one generated by a model).
    """
    path = Path(path)
    text = format_bvh(motion, channels, precision)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path
