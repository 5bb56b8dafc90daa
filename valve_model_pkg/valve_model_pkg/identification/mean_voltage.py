"""Around the drive electronics: records driven by their measured mean coil voltage.

A record of a valve in service that carries ``coil_voltage_mean`` (the mean voltage across
the coil terminals over the same interval as the current) needs no model of the drive
electronics: over every interval the coil's voltage balance (eq. 1) holds exactly in the
means, ``mean(u) dt = R mean(i) dt + psi(t_k) - psi(t_{k-1})``, whatever the boost,
chopper or release pulse did inside the interval. :func:`around_electronics` turns such a
record into one that drives the bare coil with the measured mean held over each interval
(:func:`.model_adapter.interval_segments`): the model's flux linkage then obeys the
balance with the measured voltage integral over every interval, and its current is
compared like with like (interval means against interval means). :func:`choose_route`
offers this route when every record through the electronics carries the voltage; when
they carry the main PWM commands too, the electronics route is its rival and the data
choose between them (:class:`RouteScreen`, :func:`settle_route`); a route may be forced.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from ..errors import MeasurementFormatError
from .measurement import Measurement

if TYPE_CHECKING:
    import numpy as np

__all__ = ['HOLD_EXPLAINS_LEAD', 'ROUTES_TOLD_APART', 'ROUTE_AUTO', 'ROUTE_BARE_COIL',
           'ROUTE_CHOICES', 'ROUTE_ELECTRONICS', 'ROUTE_FORCE', 'ROUTE_MEAN_VOLTAGE', 'ROUTE_TEXT',
           'Route', 'RouteScreen', 'VoltageCheck',
           'around_electronics', 'check_mean_voltage', 'choose_route', 'hold_error',
           'settle_route', 'through_drive_counterparts']

#: Records through the drive electronics, fitted through the mean coil voltage.
ROUTE_MEAN_VOLTAGE = 'mean_coil_voltage'
#: Records through the drive electronics, fitted through the model of the electronics.
ROUTE_ELECTRONICS = 'drive_electronics'
#: Bench records on the bare coil (step, pwm with its coil voltage): no electronics.
ROUTE_BARE_COIL = 'bare_coil'
#: How each route reads in the report.
ROUTE_TEXT = {
    ROUTE_MEAN_VOLTAGE: 'through the measured mean coil voltage, no electronics model',
    ROUTE_ELECTRONICS: 'through the model of the drive electronics (from the main PWM '
                       'commands)',
    ROUTE_BARE_COIL: 'the bare coil driven by the measured voltage',
}
#: ``IdentifySettings.route`` (``valve_identify --route``): the data choose.
ROUTE_AUTO = 'auto'
#: ``IdentifySettings.route`` values that force a route, and the route each forces.
ROUTE_FORCE = {'mean-voltage': ROUTE_MEAN_VOLTAGE, 'electronics': ROUTE_ELECTRONICS}
#: Every value ``IdentifySettings.route`` takes.
ROUTE_CHOICES = (ROUTE_AUTO, *ROUTE_FORCE)


@dataclass(frozen=True)
class Route:
    """How the valve is fitted (:func:`choose_route`).

    Attributes
    ----------
    name : str
        One of :data:`ROUTE_TEXT`.
    fit, validation : list of Measurement
        The records as the fit runs them.
    through_drive_fit, through_drive_validation : list of Measurement
        The records as read (through the electronics where they were), for identifying
        the electronics after the valve.
    note : str
        The route in words, with the reason when the mean voltage is not used.
    rival : Route or None
        The electronics route beside the mean-voltage route when the records carry both
        the mean voltage and the main PWM commands and no route is forced: the data
        choose (:func:`settle_route`). None: the route is settled.
    """

    name: str
    fit: list[Measurement]
    validation: list[Measurement]
    through_drive_fit: list[Measurement]
    through_drive_validation: list[Measurement]
    note: str
    rival: Route | None = None

    @property
    def text(self) -> str:
        """The route as the report says it."""
        return ROUTE_TEXT[self.name]


def around_electronics(m: Measurement) -> Measurement:
    """``m`` with its drive electronics replaced by its measured mean coil voltage.

    The bare coil is driven by ``coil_voltage_mean`` held over each current interval
    (``voltage_hold='interval_mean'``), the current compared as the record gives it; the
    discarded start and the hold-out stay as they are.

    Raises
    ------
    ValueError
        ``m`` does not carry a finite mean coil voltage on every sample.
    """
    if not m.has_coil_voltage_mean:
        raise ValueError(f'{m.source}: no finite coil_voltage_mean on every sample')
    return replace(m, drive=None, voltage_v=m.coil_voltage_mean_v.copy(),
                   voltage_hold='interval_mean',
                   notes=m.notes + ('driven by the measured coil_voltage_mean held over each '
                                    'current interval (the bare coil, no electronics model)',))


def _lacking(records: Sequence[Measurement]) -> list[str]:
    return [m.name for m in records if m.drive is not None and not m.has_coil_voltage_mean]


def _forced(force: str) -> str:
    return f' (forced: route {force!r})'


def choose_route(fit: Sequence[Measurement], validation: Sequence[Measurement],
                 force: str = ROUTE_AUTO) -> Route:
    """The route of the valve fit, or the two routes the data choose between.

    Records without drive electronics run the bare coil whatever ``force`` says. Records
    through the electronics take the mean-voltage route only when every one of them (fit
    and validation) carries a finite ``coil_voltage_mean`` on every sample; otherwise the
    electronics route, and the note names the records that lack the voltage. When they
    all carry it (and the main PWM commands, which every record through the electronics
    has), the mean-voltage route is returned with the electronics route as its
    :attr:`Route.rival`, for the data to choose (:func:`settle_route`). States of the
    suite's own simulator (bag metadata ``state_source: simulator``) run the electronics
    model that made them, without a contest: it is exact there, while the held mean leaves
    some mA where the drive switches within an interval and the spool moves.

    Parameters
    ----------
    fit, validation : sequence of Measurement
        The records as read.
    force : str
        :data:`ROUTE_AUTO`, or a key of :data:`ROUTE_FORCE`.

    Raises
    ------
    ValueError
        ``force`` is not one of :data:`ROUTE_CHOICES`.
    MeasurementFormatError
        ``force`` is ``'mean-voltage'`` and a record through the electronics lacks a
        complete ``coil_voltage_mean`` (the message names it).
    """
    if force not in ROUTE_CHOICES:
        raise ValueError(f'route: {force!r} is not one of {", ".join(ROUTE_CHOICES)}')
    fit, validation = list(fit), list(validation)
    through = [m for m in fit + validation if m.drive is not None]
    if not through:
        return Route(ROUTE_BARE_COIL, fit, validation, fit, validation,
                     'valve fitted on the bare coil driven by the measured voltage'
                     + ('' if force == ROUTE_AUTO else
                        f' (route {force!r} not applied: no record runs through drive '
                        'electronics)'))
    electronics = Route(ROUTE_ELECTRONICS, fit, validation, fit, validation,
                        f'valve fitted {ROUTE_TEXT[ROUTE_ELECTRONICS]}')
    if ROUTE_FORCE.get(force) == ROUTE_ELECTRONICS:
        return replace(electronics, note=electronics.note + _forced(force))
    lacking = _lacking(fit + validation)
    if lacking and force != ROUTE_AUTO:
        first = next(m for m in fit + validation
                     if m.drive is not None and not m.has_coil_voltage_mean)
        raise MeasurementFormatError(
            first.source, None, f'route {force!r} needs a finite coil_voltage_mean on every '
            'sample of every record through the drive electronics; this record has none '
            'or gaps')
    if force == ROUTE_AUTO and all(m.metadata.get('state_source') == 'simulator'
                                   for m in through):
        return replace(electronics, note=electronics.note + (
            ": the records are states of the suite's own simulator, whose electronics "
            'model made them exactly (the mean coil voltage, held over each interval, '
            'would only approximate the drive within the intervals)'))
    if lacking:
        carry = [m.name for m in through if m.has_coil_voltage_mean]
        why = (f' ({", ".join(lacking)} lack a complete coil_voltage_mean, which '
               f'{", ".join(carry)} carry; the mean voltage is used only when every record '
               'through the electronics carries it)') if carry else ''
        return replace(electronics, note=electronics.note + why)

    def conv(ms: list[Measurement]) -> list[Measurement]:
        return [around_electronics(m) if m.drive is not None else m for m in ms]
    around = Route(ROUTE_MEAN_VOLTAGE, conv(fit), conv(validation), fit, validation,
                   f'valve fitted {ROUTE_TEXT[ROUTE_MEAN_VOLTAGE]}: the measured '
                   'coil_voltage_mean is held over each current interval on the bare coil, '
                   'so the interval voltage balance holds with the measured voltage; '
                   'interval means of the current are compared')
    if force != ROUTE_AUTO:
        return replace(around, note=around.note + _forced(force))
    return replace(around, rival=electronics)


#: The current errors tell the two routes apart when the worse route's RMS error is at
#: least this multiple of the better one's (its own error, in quadrature, at least 0.75 of
#: the better route's). Below it a misfit common to both (an effect the baseline lacks)
#: dominates, and the mean-voltage route goes on: it has no electronics constants that
#: could absorb part of that misfit and keep it through the effect refits.
ROUTES_TOLD_APART = 1.25

#: The electronics route's lead over the mean-voltage route is the held mean's when the
#: mean-voltage route's hold error (:func:`hold_error`) is at least this share of the
#: mean-voltage route's error beyond the electronics route's (in quadrature). Below it the
#: electronics route fitted better by moving its constants into a misfit common to both
#: routes (an effect the baseline lacks), which the effect refits would then not find: the
#: mean-voltage route goes on.
HOLD_EXPLAINS_LEAD = 0.5


@dataclass(frozen=True)
class RouteScreen:
    """The two routes' baselines compared after the search on the search window.

    Attributes
    ----------
    rmse_a : dict
        RMS current error of each route's baseline [A] on the compared records, by route
        name (:data:`ROUTE_MEAN_VOLTAGE`, :data:`ROUTE_ELECTRONICS`).
    criterion : dict
        The figure that decides, by route name: the RMS error on the hold-out records, or
        the Bayesian information criterion on the fit window without them.
    compared_on : str
        What the figures are taken on, in words.
    voltage : VoltageCheck or None
        How well the electronics route's drive reproduces the measured mean coil voltage
        (reported, not deciding).
    hold_error_a : float or None
        The mean-voltage route's hold error on the compared records [A] (:func:`hold_error`,
        with the electronics route's valve and drive); None: not measured.
    """

    rmse_a: dict[str, float]
    criterion: dict[str, float]
    compared_on: str
    voltage: VoltageCheck | None = None
    hold_error_a: float | None = None

    @property
    def told_apart(self) -> bool:
        """True when the current errors tell the routes apart (:data:`ROUTES_TOLD_APART`)."""
        a, b = sorted(self.rmse_a[r] for r in (ROUTE_MEAN_VOLTAGE, ROUTE_ELECTRONICS))
        if not (math.isfinite(a) and math.isfinite(b) and a > 0.0):
            return True
        return b >= ROUTES_TOLD_APART * a

    @property
    def lead_a(self) -> float:
        """The mean-voltage route's RMS error beyond the electronics route's, in quadrature
        [A] (0 when the electronics route is not better; inf when the mean-voltage route's
        error is not finite)."""
        mv, el = self.rmse_a[ROUTE_MEAN_VOLTAGE], self.rmse_a[ROUTE_ELECTRONICS]
        if not math.isfinite(mv):
            return math.inf
        if not math.isfinite(el):
            return 0.0
        return math.sqrt(max(mv * mv - el * el, 0.0))

    @property
    def hold_explains_lead(self) -> bool:
        """True when the hold error accounts for the electronics route's lead
        (:data:`HOLD_EXPLAINS_LEAD`), or when it was not measured."""
        h = self.hold_error_a
        if h is None or not math.isfinite(h) or not math.isfinite(self.lead_a):
            return True
        return h >= HOLD_EXPLAINS_LEAD * self.lead_a

    @property
    def chosen(self) -> str:
        """The route with the lower criterion when the current errors tell them apart,
        else the mean-voltage route (also when neither is finite: it needs no electronics
        model). The electronics route's lower criterion counts only when the held mean's
        error accounts for its lead (:attr:`hold_explains_lead`)."""
        if not self.told_apart:
            return ROUTE_MEAN_VOLTAGE
        mv, el = self.criterion[ROUTE_MEAN_VOLTAGE], self.criterion[ROUTE_ELECTRONICS]
        if (math.isfinite(el) and (el < mv or not math.isfinite(mv))
                and self.hold_explains_lead):
            return ROUTE_ELECTRONICS
        return ROUTE_MEAN_VOLTAGE

    def to_json(self) -> dict[str, object]:
        """``report.json`` ``route.chosen_by_data``."""
        v = self.voltage
        return {'chosen': self.chosen, 'rmse_a': dict(self.rmse_a),
                'criterion': dict(self.criterion), 'compared_on': self.compared_on,
                'told_apart_by_the_current': self.told_apart,
                'electronics_voltage_rmse_v': v.rmse_v if v is not None else None,
                'hold_error_a': self.hold_error_a,
                'hold_explains_lead': self.hold_explains_lead,
                'statement': self.statement()}

    def statement(self) -> str:
        """The choice in words, with both routes' errors."""
        other = (ROUTE_ELECTRONICS if self.chosen == ROUTE_MEAN_VOLTAGE
                 else ROUTE_MEAN_VOLTAGE)
        text = (f'route chosen by the data: the records carry both the mean coil voltage '
                f'and the PWM commands; each route\'s baseline, searched on the search '
                f'window, misses {self.compared_on} by '
                f'{1e3 * self.rmse_a[self.chosen]:.3g} mA RMS on the chosen route against '
                f'{1e3 * self.rmse_a[other]:.3g} mA {ROUTE_TEXT[other]}')
        v = self.voltage
        check = f'; {v.statement()}' if v is not None else ''
        h = self.hold_error_a
        if h is not None and math.isfinite(h):
            check += (f'; holding the electronics\' own mean voltage over each interval '
                      f'changes their current by {1e3 * h:.3g} mA RMS (the mean-voltage '
                      'route\'s hold error)')
        if self.told_apart and not self.hold_explains_lead:
            return text + (
                f' (the electronics route\'s lead, {1e3 * self.lead_a:.3g} mA in quadrature, '
                'is not the held mean\'s: its constants absorbed a misfit common to both '
                f'routes, and the mean-voltage route goes on{check})')
        if self.told_apart:
            return text + check
        return text + (
            f' (within a factor {ROUTES_TOLD_APART:g}: a misfit common to both routes '
            'dominates, and the mean-voltage route goes on, with no electronics constants '
            f'to absorb part of it{check})')


def settle_route(route: Route, screen: RouteScreen) -> Route:
    """The route ``screen`` chose among ``route`` and its :attr:`Route.rival`, settled, its
    note saying why and the other route's error."""
    chosen = route.rival if screen.chosen == ROUTE_ELECTRONICS else route
    return replace(chosen, rival=None, note=f'{chosen.note}; {screen.statement()}')


def through_drive_counterparts(route: Route, prepared: Sequence[Measurement]
                               ) -> list[Measurement]:
    """The records as read (through the electronics) over the same span as the prepared
    records of the mean-voltage route (hold-out and windows applied): what the drive
    electronics are identified on once the valve is known."""
    originals = {m.source: m for m in route.through_drive_fit if m.drive is not None}
    out = []
    for p in prepared:
        m = originals.get(p.source)
        if m is None:
            continue
        keep = m.t_s <= p.t_s[-1]
        out.append(replace(m.samples(keep), exclude_before_s=p.exclude_before_s,
                           held_out_from_s=p.held_out_from_s))
    return out


@dataclass(frozen=True)
class VoltageCheck:
    """How well drive electronics reproduce a record's measured mean coil voltage.

    Attributes
    ----------
    rmse_v : float
        RMS of the measured minus the simulated interval-mean coil voltage [V] over the
        compared samples of every record.
    supply_v : float
        The drive supply voltage [V] (the scale of the error).
    samples : int
        Samples compared.
    """

    rmse_v: float
    supply_v: float
    samples: int

    def statement(self) -> str:
        """The check in words."""
        return (f'the identified electronics reproduce the measured coil_voltage_mean to '
                f'{self.rmse_v:.3g} V RMS ({100.0 * self.rmse_v / self.supply_v:.3g} % of the '
                f'{self.supply_v:g} V supply) over {self.samples} samples')


def _coil_voltage_means(m: Measurement, params: object, electronics: object,
                        parallel: bool = True) -> np.ndarray:
    """Interval-mean coil voltage [V] at ``m.t_s`` of ``m``'s PWM commands through
    ``electronics``, the valve at ``params`` (eqs. 1-11 with the drive)."""
    import numpy as np

    from ..model import InputTrace, simulate_trace_batch
    d = m.drive
    res = simulate_trace_batch(
        params, InputTrace.pwm_commands(d.t_s, d.duty, d.pwm_frequency_hz,
                                        d.supply_voltage_v),
        m.t_s, electronics=electronics, sampling='interval_mean',
        supply_pressure_pa=float(m.supply_pressure_pa),
        output_pressure_pa=float(m.output_pressure_pa), parallel=parallel)
    return np.asarray(res.coil_voltage_v, dtype=float).reshape(-1)


def check_mean_voltage(records: Sequence[Measurement], params: object,
                       electronics: object) -> VoltageCheck | None:
    """Simulate ``records`` through ``electronics`` with the valve at ``params`` and
    compare the interval-mean coil voltage with the measured ``coil_voltage_mean``.

    Parameters
    ----------
    records : sequence of Measurement
        Records through the electronics that carry the mean coil voltage.
    params : ValveParameters
        The valve.
    electronics : ElectronicsConfig
        The drive electronics.

    Returns
    -------
    VoltageCheck or None
        ``None`` when no record carries the voltage.
    """
    import numpy as np

    errors, supply = [], 0.0
    for m in records:
        if m.drive is None or not m.has_coil_voltage_mean or m.supply_pressure_pa is None:
            continue
        sim = _coil_voltage_means(m, params, electronics)
        keep = m.t_s >= m.exclude_before_s
        errors.append((m.coil_voltage_mean_v - sim)[keep])
        supply = max(supply, float(np.max(m.drive.supply_voltage_v)))
    if not errors:
        return None
    err = np.concatenate(errors)
    return VoltageCheck(float(np.sqrt(np.mean(err ** 2))), supply, int(err.size))


def hold_error(records: Sequence[Measurement], params: object, electronics: object
               ) -> float | None:
    """The mean-voltage route's hold error on ``records``: the RMS difference [A] between
    the interval-mean current through ``electronics`` and the one of the bare coil driven
    by the electronics' own interval-mean coil voltage held over each interval (as
    :func:`around_electronics` drives it), the valve at ``params`` in both.

    Both runs obey the interval voltage balance (eq. 1) with the same voltage integrals;
    they differ only by what happens inside an interval (the current's course under the
    switched voltage, the spool moving meanwhile). That is what the electronics route can
    follow and the mean-voltage route cannot, measured on the electronics route's own
    model.

    Parameters
    ----------
    records : sequence of Measurement
        Records through the electronics (``drive``); others are skipped.
    params : ValveParameters
        The valve.
    electronics : ElectronicsConfig
        The drive electronics.

    Returns
    -------
    float or None
        RMS over the compared samples (``Measurement.valid``) of every record; None when no
        record runs through the electronics.
    """
    import numpy as np

    from .model_adapter import prepare_trace, simulate_measurement
    raw = params.to_vector()[None, :]
    errors = []
    for m in records:
        if m.drive is None or m.supply_pressure_pa is None:
            continue
        volts = _coil_voltage_means(m, params, electronics, parallel=False)
        through, _ = simulate_measurement(raw, prepare_trace(m), parallel=False,
                                          electronics=electronics)
        held_m = replace(m, drive=None, voltage_v=volts, voltage_hold='interval_mean')
        held, _ = simulate_measurement(raw, prepare_trace(held_m), parallel=False)
        diff = (through[0] - held[0])[m.valid]
        errors.append(diff[np.isfinite(diff)])
    if not errors:
        return None
    err = np.concatenate(errors)
    return float(np.sqrt(np.mean(err ** 2))) if err.size else None
