"""The suite's topics and their message types, as a recorder needs them (no ROS import).

The names and types are defined once in :mod:`valve_model_pkg.interface`.
"""
from __future__ import annotations

from valve_model_pkg.interface import SUITE_TOPICS

__all__ = ['SUITE_TOPICS', 'DEFAULT_TOPICS', 'parse_topic_spec']

#: What ``valve_recorder`` records when no topic is given: all of the suite's topics.
DEFAULT_TOPICS: tuple[str, ...] = tuple(SUITE_TOPICS)


def parse_topic_spec(spec: str) -> tuple[str, str | None]:
    """Split a topic entry ``name`` or ``name:type`` into ``(name, type or None)``.

    A name without a type takes the suite's type when it is one of :data:`SUITE_TOPICS`
    (with or without the leading slash); otherwise the type is ``None`` and the recorder
    discovers it from the ROS graph.

    Parameters
    ----------
    spec : str
        ``valve/state``, ``/valve/state`` or ``my/topic:my_pkg/msg/MyType``.

    Returns
    -------
    tuple of (str, str or None)
        Topic name as given (not resolved) and message type in ``pkg/msg/Name`` form.

    Raises
    ------
    ValueError
        Empty name, or a type not of the form ``pkg/msg/Name`` (``pkg/Name`` is expanded).
    """
    name, sep, msgtype = spec.strip().partition(':')
    name = name.strip()
    if not name:
        raise ValueError(f'topic entry {spec!r} has no topic name')
    if sep:
        msgtype = msgtype.strip()
        parts = msgtype.split('/')
        if len(parts) == 2 and all(parts):
            msgtype = f'{parts[0]}/msg/{parts[1]}'
        elif not (len(parts) == 3 and all(parts) and parts[1] == 'msg'):
            raise ValueError(f'topic entry {spec!r}: type {msgtype!r} is not of the form '
                             'pkg/msg/Name')
        return name, msgtype
    known = SUITE_TOPICS.get(name) or SUITE_TOPICS.get(name.lstrip('/')) \
        or SUITE_TOPICS.get('/' + name)
    return name, known
