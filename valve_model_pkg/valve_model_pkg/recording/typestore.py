"""Message types for bags: rosbags typestores that know the suite's and the bag's messages.

rosbags ships the standard ROS 2 Jazzy types (std_msgs, sensor_msgs, diagnostic_msgs,
...). The suite's own types (``valve_msgs``) and any other package's types are parsed from
their ``.msg`` files, found in the ament prefixes (``share/<pkg>/msg/<Name>.msg``, the
colcon install or a ROS install) or, for ``valve_msgs``, in the source tree next to this
package. The definitions parsed this way give the same RIHS01 type hashes as rosidl (a
unit test checks it against the ``.json`` type descriptions rosidl installs), so a bag's
``type_description_hash`` matches what a ROS 2 Jazzy install computes.

A bag is decoded with the definitions it embeds (MCAP schemas, the sqlite3
``message_definitions`` table) and, for the types it does not embed, with the installed
ones (:func:`typestore_for_bag`).
"""
from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from rosbags.interfaces import Connection, MessageDefinitionFormat, Nodetype
from rosbags.typesys import (Stores, TypesysError, get_types_from_idl, get_types_from_msg,
                             get_typestore)
from rosbags.typesys.store import Typestore

from ..errors import BagFormatError, UnknownMessageTypeError

__all__ = ['SUITE_MSG_PACKAGE', 'TypeDefinition', 'build_typestore', 'ensure_type',
           'find_msg_file', 'msg_search_dirs', 'source_msg_dir', 'msgdef_and_hash',
           'typestore_for_bag']

_LOG = logging.getLogger(__name__)

#: The suite's interface package, always registered by :func:`build_typestore`.
SUITE_MSG_PACKAGE = 'valve_msgs'


def source_msg_dir() -> Path:
    """``valve_msgs/msg`` of the source tree this module belongs to (may not exist)."""
    # recording/ -> valve_model_pkg (module) -> valve_model_pkg (package dir) -> repo root
    return Path(__file__).resolve().parents[3] / SUITE_MSG_PACKAGE / 'msg'


def msg_search_dirs(package: str, extra_dirs: Iterable[str | Path] = ()) -> list[Path]:
    """Directories that may hold ``<package>``'s ``.msg`` files, most specific first.

    Parameters
    ----------
    package : str
        ROS package name, e.g. ``valve_msgs``.
    extra_dirs : iterable of path
        Directories given by the caller; searched first (both ``dir/<Name>.msg`` and
        ``dir/<package>/msg/<Name>.msg`` layouts).

    Returns
    -------
    list of pathlib.Path
        Existing directories only.
    """
    candidates: list[Path] = []
    for d in extra_dirs:
        candidates += [Path(d), Path(d) / package / 'msg']
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / 'share' / package / 'msg')
    if package == SUITE_MSG_PACKAGE:
        candidates.append(source_msg_dir())
    seen: set[Path] = set()
    out = []
    for c in candidates:
        if c.is_dir() and c not in seen:
            seen.add(c)
            out.append(c)
    return out


def find_msg_file(msgtype: str, extra_dirs: Iterable[str | Path] = ()) -> Path | None:
    """The ``.msg`` file defining ``pkg/msg/Name``, or ``None`` when none is found."""
    package, _, name = msgtype.split('/', 2) if msgtype.count('/') == 2 else ('', '', '')
    if not package:
        return None
    for d in msg_search_dirs(package, extra_dirs):
        if (d / f'{name}.msg').is_file():
            return d / f'{name}.msg'
    return None


def _referenced_types(fields: Sequence[tuple[str, tuple]]) -> set[str]:
    """Complex types a parsed field list refers to."""
    out: set[str] = set()
    for _, desc in fields:
        node, sub = desc
        if node == Nodetype.NAME:
            out.add(sub)
        elif node in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            inner_node, inner = sub[0]
            if inner_node == Nodetype.NAME:
                out.add(inner)
    return out


def ensure_type(store: Typestore, msgtype: str, extra_dirs: Iterable[str | Path] = ()) -> None:
    """Register ``msgtype`` and the types it uses from ``.msg`` files, unless known.

    Parameters
    ----------
    store : rosbags Typestore
        Modified in place.
    msgtype : str
        ``pkg/msg/Name``.
    extra_dirs : iterable of path
        More directories to look for ``.msg`` files in (see :func:`msg_search_dirs`).

    Raises
    ------
    UnknownMessageTypeError
        No definition of ``msgtype`` (or of a type it uses) is found.
    """
    extra_dirs = list(extra_dirs)
    pending = [msgtype]
    parsed: dict[str, tuple] = {}
    while pending:
        name = pending.pop()
        if name in store.fielddefs or name in parsed:
            continue
        path = find_msg_file(name, extra_dirs)
        if path is None:
            where = ', '.join(str(d) for d in msg_search_dirs(name.split('/')[0], extra_dirs))
            raise UnknownMessageTypeError(
                f'no definition of message type {name!r}'
                + (f' (needed by {msgtype!r})' if name != msgtype else '')
                + f'; searched the rosbags Jazzy types and {where or "no existing directory"}'
                ' (is the package built and its install sourced?)')
        try:
            types = get_types_from_msg(path.read_text(encoding='utf-8'), name)
        except TypesysError as err:
            raise UnknownMessageTypeError(f'{path} cannot be parsed: {err}') from err
        parsed.update(types)
        for consts_fields in types.values():
            pending.extend(_referenced_types(consts_fields[1]))
    if parsed:
        store.register(parsed)
        _LOG.debug('registered %s from .msg files', sorted(parsed))


def build_typestore(msgtypes: Iterable[str] = (),
                    extra_dirs: Iterable[str | Path] = ()) -> Typestore:
    """A rosbags typestore: ROS 2 Jazzy types plus ``valve_msgs`` plus ``msgtypes``.

    Parameters
    ----------
    msgtypes : iterable of str
        Further types to register from ``.msg`` files (``pkg/msg/Name``).
    extra_dirs : iterable of path
        More directories to look for ``.msg`` files in.

    Returns
    -------
    rosbags Typestore
        A new store; the caller may register more types in it.

    Raises
    ------
    UnknownMessageTypeError
        ``valve_msgs`` or one of ``msgtypes`` has no definition.
    """
    extra_dirs = list(extra_dirs)
    store = get_typestore(Stores.ROS2_JAZZY)
    dirs = msg_search_dirs(SUITE_MSG_PACKAGE, extra_dirs)
    if not dirs:
        raise UnknownMessageTypeError(
            f'no {SUITE_MSG_PACKAGE}/msg directory found (ament prefixes: '
            f'{os.environ.get("AMENT_PREFIX_PATH", "unset")}, source tree: {source_msg_dir()})')
    for msg_file in sorted(dirs[0].glob('*.msg')):
        ensure_type(store, f'{SUITE_MSG_PACKAGE}/msg/{msg_file.stem}', extra_dirs)
    for msgtype in msgtypes:
        ensure_type(store, msgtype, extra_dirs)
    return store


def msgdef_and_hash(store: Typestore, msgtype: str) -> tuple[str, str]:
    """The ``ros2msg`` definition (dependencies appended) and RIHS01 hash of ``msgtype``.

    This is what goes into a bag: the MCAP schema (encoding ``ros2msg``) and the
    ``type_description_hash`` of ``metadata.yaml``.
    """
    if msgtype not in store.fielddefs:
        raise UnknownMessageTypeError(f'message type {msgtype!r} is not in the typestore')
    msgdef, _ = store.generate_msgdef(msgtype, ros_version=2)
    return msgdef, store.hash_rihs01(msgtype)


@dataclass(frozen=True)
class TypeDefinition:
    """A message type as a bag records it.

    Attributes
    ----------
    msgtype : str
        ``pkg/msg/Name``.
    encoding : str
        ``ros2msg`` or ``ros2idl`` for an embedded definition; ``''`` when the bag embeds
        none (sqlite3 bags written before Iron, hand-made bags).
    text : str
        The embedded definition (dependencies appended, as rosbag2 writes it).
    digest : str
        The RIHS01 type hash the bag records; ``''`` when it records none.
    """

    msgtype: str
    encoding: str = ''
    text: str = ''
    digest: str = ''

    @classmethod
    def of_connection(cls, connection: Connection) -> 'TypeDefinition':
        """The type of a rosbags connection, with the definition the storage embeds."""
        encoding = {MessageDefinitionFormat.MSG: 'ros2msg',
                    MessageDefinitionFormat.IDL: 'ros2idl'}.get(connection.msgdef.format, '')
        return cls(connection.msgtype, encoding, connection.msgdef.data, connection.digest)


def _parse_definition(definition: TypeDefinition, source: str) -> dict:
    """rosbags field definitions of an embedded ``ros2msg``/``ros2idl`` definition."""
    try:
        if definition.encoding == 'ros2msg':
            return dict(get_types_from_msg(definition.text, definition.msgtype))
        if definition.encoding == 'ros2idl':
            sep = '=' * 80 + '\n'
            parts = definition.text.split(sep)[1:] if definition.text.startswith(
                sep + 'IDL: ') else ['\n' + definition.text]
            types: dict = {}
            for part in parts:
                types.update(get_types_from_idl(part.split('\n', 1)[1]))
            return types
    except TypesysError as err:
        raise BagFormatError(f'{source}: the embedded definition of {definition.msgtype!r} '
                             f'cannot be parsed: {err}') from err
    raise BagFormatError(f'{source}: the definition of {definition.msgtype!r} has encoding '
                         f'{definition.encoding!r}; expected ros2msg or ros2idl')


def _closure(store: Typestore, msgtype: str) -> list[str]:
    """``msgtype`` and every type it uses, from ``store``."""
    out: list[str] = []
    pending = [msgtype]
    while pending:
        name = pending.pop()
        if name in out:
            continue
        out.append(name)
        pending.extend(_referenced_types(store.fielddefs[name][1]))
    return out


def typestore_for_bag(definitions: Iterable[TypeDefinition], source: str) -> Typestore:
    """A typestore that decodes every type of a bag.

    A type is decoded with the definition the bag embeds; a type the bag does not embed is
    taken from the ROS 2 Jazzy types or the installed ``.msg`` files (:func:`ensure_type`:
    the ament prefixes, the colcon install, ``valve_msgs`` of the source tree). When the
    bag records a type hash, an installed definition must give the same hash, so a bag is
    never decoded with a definition other than the one it was recorded with.

    Parameters
    ----------
    definitions : iterable of TypeDefinition
        The types of the bag's topics.
    source : str
        The bag, for the error messages.

    Returns
    -------
    rosbags Typestore
        Knows every ``msgtype`` of ``definitions``.

    Raises
    ------
    BagFormatError
        An embedded definition cannot be parsed or contradicts another one, or an installed
        definition has another type hash than the bag records.
    UnknownMessageTypeError
        A type the bag does not embed has no definition installed either.
    """
    definitions = list(definitions)
    types: dict = {}
    for d in definitions:
        if d.encoding and d.msgtype not in types:
            types.update(_parse_definition(d, source))
    store = get_typestore(Stores.EMPTY)
    try:
        store.register(types)
    except TypesysError as err:
        raise BagFormatError(f'{source}: the embedded message definitions contradict each '
                             f'other: {err}') from err
    installed: Typestore | None = None
    for d in definitions:
        if d.msgtype in store.fielddefs:
            continue
        if installed is None:
            installed = get_typestore(Stores.ROS2_JAZZY)
        try:
            ensure_type(installed, d.msgtype)
        except UnknownMessageTypeError as err:
            raise UnknownMessageTypeError(f'{source}: the bag does not embed the definition '
                                          f'of {d.msgtype!r}, and {err}') from err
        store.register({name: installed.fielddefs[name]
                        for name in _closure(installed, d.msgtype)
                        if name not in store.fielddefs})
        if d.digest and store.hash_rihs01(d.msgtype) != d.digest:
            raise BagFormatError(
                f'{source}: the bag does not embed the definition of {d.msgtype!r}, and the '
                f'installed one differs from the one it was recorded with (type hash '
                f'{d.digest} in the bag, {store.hash_rihs01(d.msgtype)} installed)')
        _LOG.debug('%s: %s decoded with the installed definition', source, d.msgtype)
    return store
