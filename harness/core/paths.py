"""File-system-safe names: a run file's strings never choose a path outside the output folder.

``safe_name(text)`` maps any string to one safe path component:

- Unicode is normalised (NFKC); letters and digits of any script, ``-``, ``_``, ``+`` and
  ``.`` are kept; every other character (path separators ``/`` and ``\\``, control
  characters, spaces, ``:``, quotes, ...) becomes ``_``, and runs of ``_`` collapse to one.
- Runs of dots collapse to one dot (so no ``..`` remains) and leading dots, ``_`` and ``-``
  are removed (no hidden files, nothing read as an option); trailing dots and spaces too.
- The result is at most ``MAX_NAME_BYTES`` bytes of UTF-8 (well under the usual 255).
- If anything was changed, ``-`` and the first 8 hex digits of the SHA-256 of the original
  text are appended, so two different unsafe names do not map to the same directory.
- An empty result becomes ``unnamed`` (plus the hash when the original was not empty).

A name that is already safe (``slew-rw``, ``case-a-beta-0.8``) is returned unchanged.

``safe_child(base, *names)`` joins ``safe_name`` of each name to ``base`` and checks that the
resolved path is inside the resolved ``base``; otherwise it raises ``UnsafePathError`` (a
``ConfigError``) naming the offending value.
"""

from __future__ import annotations

import hashlib
import re
import unicodedata
from pathlib import Path

from rig_models.schema import ConfigError

MAX_NAME_BYTES = 120
_KEEP = frozenset("-_+.")


class UnsafePathError(ConfigError):
    """A name would put a file outside the output folder."""


def _hash8(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()[:8]


def _truncate_utf8(text: str, max_bytes: int) -> str:
    raw = text.encode("utf-8")
    if len(raw) <= max_bytes:
        return text
    return raw[:max_bytes].decode("utf-8", "ignore")


def safe_name(text: str) -> str:
    """One file-system-safe path component for ``text`` (see the module docstring)."""
    original = str(text)
    norm = unicodedata.normalize("NFKC", original)
    chars = []
    for ch in norm:
        cat = unicodedata.category(ch)
        if ch in _KEEP or (cat[0] in "LN" and ch.isprintable()):
            chars.append(ch)
        else:
            chars.append("_")
    out = "".join(chars)
    out = re.sub(r"_+", "_", out)
    out = re.sub(r"\.{2,}", ".", out)
    out = out.lstrip("._-").rstrip(". ")
    changed = out != original
    suffix = f"-{_hash8(original)}" if changed and original else ""
    out = _truncate_utf8(out, MAX_NAME_BYTES - len(suffix)).rstrip(". ")
    if not out:
        out = "unnamed"
    out += suffix
    assert out not in (".", "..") and "/" not in out and "\\" not in out and "\x00" not in out
    return out


def safe_child(base: Path, *names: str) -> Path:
    """``base / safe_name(n1) / safe_name(n2) ...``, checked to stay inside ``base``."""
    base = Path(base)
    path = base
    for name in names:
        if not isinstance(name, str):
            raise UnsafePathError(f"path name {name!r}: expected a string")
        path = path / safe_name(name)
    root = base.resolve()
    resolved = path.resolve()
    if resolved != root and root not in resolved.parents:
        raise UnsafePathError(
            f"name {'/'.join(names)!r} would write to {resolved}, outside the output folder "
            f"{root}")
    return path
