"""Reading a YAML file a person wrote (run, suite, rig, criteria files), bounded.

A YAML file of tens of MB, or a small one whose aliases expand to millions of values (each
``*alias`` repeats a whole subtree: ten levels of ten aliases are 10^10 values), took
gigabytes and minutes or died with MemoryError, and a recursive alias (``&a [*a]``) never
ends for code that walks the document. ``load_yaml`` refuses a file over
``MAX_YAML_BYTES`` before reading it, and a document whose values, counted as expanded,
exceed ``MAX_YAML_VALUES``, with a ``ConfigError`` naming the file.

Only a regular file is read: a FIFO blocked ``open()`` until a writer came (for ever, and
deaf to SIGTERM), a device or a socket never ends. The file is opened without blocking and
checked to be regular on its open descriptor, so nothing swapped in after a first check can
block either.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any

import yaml

from rig_models.schema import ConfigError

MAX_YAML_BYTES = 4 * 1024 * 1024
"""The largest file: the biggest built-in run, suite or rig file is about 10 KB."""

MAX_YAML_VALUES = 200_000
"""The most values (mappings, lists and scalars, aliases counted as expanded) a file may
hold: the biggest built-in file has about a thousand."""


def count_values(doc: Any, limit: int = MAX_YAML_VALUES) -> int:
    """Values of ``doc`` with every shared or recursive reference counted again; stops
    (returning more than ``limit``) as soon as the count passes ``limit``."""
    n = 0
    stack = [doc]
    while stack:
        v = stack.pop()
        n += 1
        if n > limit:
            return n
        if isinstance(v, dict):
            stack.extend(v.keys())
            stack.extend(v.values())
        elif isinstance(v, list | tuple | set):
            stack.extend(v)
    return n


def check_expansion(doc: Any, source: str) -> Any:
    """``doc`` if it is small enough once expanded and every string in it (keys too) can be
    written as UTF-8; else ``ConfigError`` naming ``source`` (and the key)."""
    if count_values(doc) > MAX_YAML_VALUES:
        raise ConfigError(f"{source}: more than {MAX_YAML_VALUES} values once its aliases "
                          "are expanded; a run, suite or rig file needs far fewer")
    _check_strings(doc, source)
    return doc


def _check_strings(doc: Any, source: str) -> None:
    # a YAML escape such as "\ud800" gives a lone surrogate: no file name, JSON report or
    # recording can hold it (names of suites and tests ended in UnicodeEncodeError)
    stack: list[tuple[Any, str]] = [(doc, "")]
    while stack:
        v, path = stack.pop()
        if isinstance(v, str):
            try:
                v.encode("utf-8")
            except UnicodeEncodeError as exc:
                raise ConfigError(f"{source}: {path or 'value'}: {v!r} holds a character "
                                  f"that is not text ({v[exc.start]!r}, a lone surrogate)"
                                  ) from None
        elif isinstance(v, dict):
            for k, item in v.items():
                key = f"{path}.{k}" if path else str(k)
                stack.append((k, f"{key} (the key)"))
                stack.append((item, key))
        elif isinstance(v, list | tuple):
            stack.extend((item, f"{path}[{i}]") for i, item in enumerate(v))


def file_kind(mode: int) -> str:
    """What a file that is not a regular one is, in words."""
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device")):
        if test(mode):
            return name
    return "not a regular file"


def open_regular(path: Path, source: str) -> int:
    """A descriptor of ``path`` opened for reading, checked to be a regular file; else
    ``ConfigError`` naming ``source``. Opened with ``O_NONBLOCK`` (a FIFO's open returns at
    once instead of waiting for a writer), then checked on the descriptor itself."""
    mode = os.stat(path).st_mode  # a directory or device refused before any open
    if not stat.S_ISREG(mode):
        raise ConfigError(f"{source}: {file_kind(mode)}, not a regular file")
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise ConfigError(f"{source}: {file_kind(mode)}, not a regular file")
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_regular_text(path: Path, source: str, limit: int, what: str) -> str:
    """The UTF-8 text of the regular file ``path``, at most ``limit`` bytes; else
    ``ConfigError`` naming ``source`` (``OSError``, ``UnicodeDecodeError`` pass)."""
    fd = open_regular(path, source)
    with open(fd, encoding="utf-8", errors="strict") as f:
        size = os.fstat(fd).st_size
        if size > limit:
            raise ConfigError(f"{source}: {size / 2**20:.1f} MiB, more than the "
                              f"{limit // 2**20} MiB {what} may have")
        return f.read(limit + 1)


def load_yaml(path: Path, what: str = "file") -> Any:
    """The document of ``path``; ``ConfigError`` (naming ``what`` and the file) when it is
    too big, expands too far, is not valid YAML, or cannot be read."""
    path = Path(path)
    source = f"{what} {path}"
    if len(source) > 300:  # a path of thousands of characters: its ends say which
        source = f"{source[:150]}...{source[-150:]}"
    try:
        text = read_regular_text(path, source, MAX_YAML_BYTES, "a YAML input")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{source}: not UTF-8 text ({exc.reason} at byte {exc.start})"
                          ) from None
    except ConfigError:
        raise  # already one line naming the file
    except (OSError, ValueError) as exc:
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise ConfigError(f"{source}: cannot read: {why}") from None
    if len(text) > MAX_YAML_BYTES:  # it grew since its size was read
        raise ConfigError(f"{source}: more than the {MAX_YAML_BYTES // 2**20} MiB a YAML "
                          "input may have")
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: not valid YAML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{source}: nested too deeply") from None
    return check_expansion(doc, source)
