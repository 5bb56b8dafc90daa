"""Which parameters the data pin down: local sensitivity and confidence analysis.

At the identified point the simulated current is differentiated with respect to the
logarithm of each free parameter (central differences, one batch), which gives the
Jacobian ``J`` (samples x parameters) in "ampere per relative change". With the bench
noise ``sigma`` estimated from the residual, the Fisher information is
``F = J^T J / sigma^2`` and ``F^-1`` approximates the covariance of the log-parameters,
i.e. of their *relative* errors. The analysis reports, per parameter:

* ``sensitivity_ma``: RMS change of the current for a 1 % change of the parameter alone;
* ``rel_std_pct``: its standard error (from the full covariance, so correlated
  parameters that trade off against each other show large errors even when each one
  alone moves the current);
* ``ci95_pct``: the 95 % half-width; a parameter counts as *pinned down* when it is
  below 5 %.

Eigen-directions of ``F`` with a small eigenvalue are the combinations the data cannot
see; they are reported as products of powers (e.g. ``l_c^0.71 mu_r^0.71``: the data fix
``l_c / mu_r`` but not ``l_c mu_r`` - eqs. (4) and (8) contain ``l_c`` and ``mu_r`` only
as ``l_c / mu_r``).

The confidence intervals are local and assume white noise: with a structured residual
(a missing effect) they are optimistic, which the report says.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..model.parameters import ValveParameters
from .problem import GAP, PAPER_SYMBOLS, FitData, ParameterSpace, equivalent_gap_m

__all__ = ['SensitivityReport', 'analyse_sensitivity', 'noise_std', 'noise_estimate',
           'NoiseEstimate', 'equivalent_gap_m',
           'residual_inflation', 'misfit_floor_pct', 'perturbed_values',
           'file_jacobians', 'current_jacobian', 'JACOBIAN_STEP']

_PINNED_CI95_PCT = 5.0
#: NRMSE [%] above which the intervals are floored at the NRMSE.
_MISFIT_NRMSE_PCT = 5.0
#: Relative step of the finite differences of the current [1].
JACOBIAN_STEP = 0.01
#: Further finite-difference steps that check the Jacobian for jumps (see
#: analyse_sensitivity), and the spread of a column's size that counts as not smooth.
_CHECK_STEPS = (0.003, 0.03)
_ROUGH_RATIO = 2.0
# Standard error beyond which a direction counts as not determined at all [%].
_NULL_STD_PCT = 100.0


@dataclass(frozen=True)
class NoiseEstimate:
    """The noise of a residual, with the current's quantisation counted.

    Attributes
    ----------
    std_a : float
        Standard deviation of the noise model [A]: ``sqrt(noise^2 + LSB^2 / 12)``.
    noise_a : float
        The noise the residual's first differences show [A].
    lsb_a : float
        Quantisation step of the current [A] (0: none).
    """

    std_a: float
    noise_a: float
    lsb_a: float = 0.0

    @property
    def quantisation_share(self) -> float:
        """Share of the noise model's variance that is quantisation, ``LSB^2 / 12 / std^2``
        [1]: a lower bound where the noise dithers the steps (``noise_a`` then holds part of
        the rounding)."""
        if not (self.lsb_a > 0.0 and self.std_a > 0.0):
            return 0.0
        return min(1.0, self.lsb_a ** 2 / 12.0 / self.std_a ** 2)


def noise_estimate(residual: np.ndarray, lsb_a: float | None = None) -> NoiseEstimate:
    """Measurement noise of a residual, from its first differences [A].

    A smooth model error hardly changes from sample to sample, white noise does, so
    ``std(diff(r)) / sqrt(2)`` estimates the noise even where the residual is structured.
    Without quantisation a robust scale (median absolute deviation) ignores single spikes.

    A quantised current (step ``lsb_a``) carries a rounding error uniform over one step,
    variance ``LSB^2 / 12``, and the noise model is ``sigma^2 = noise^2 + LSB^2 / 12``.
    The differences of such a current are whole steps, so their median absolute deviation
    is 0 while the noise is below a step: ``noise`` is then the RMS of the differences
    over sqrt(2) (those beyond ``max(4 LSB, 5 MAD)`` dropped as spikes). Where the noise
    does not dither the steps (a clean record) the rounding error of a smooth current
    changes slowly and the differences hardly see it; where it dithers them they hold part
    of it, and the model is then conservative by at most about a quarter (noise of 0.1-0.3
    steps): it never reads rounding as structure.

    Parameters
    ----------
    residual : numpy.ndarray, shape (n,)
        Measured minus simulated current [A] (``nan`` ignored).
    lsb_a : float, optional
        Quantisation step of the current [A]; None or 0: not quantised.
    """
    r = residual[np.isfinite(residual)]
    lsb = float(lsb_a) if lsb_a else 0.0
    if r.size < 4:
        return NoiseEstimate(math.nan, math.nan, lsb)
    d = np.diff(r)
    d = d - np.median(d)
    mad_scale = 1.4826 * float(np.median(np.abs(d)))
    if lsb <= 0.0:
        s = mad_scale / math.sqrt(2.0)
        return NoiseEstimate(s, s, 0.0)
    keep = np.abs(d) <= max(4.0 * lsb, 5.0 * mad_scale)
    noise2 = float(np.mean(d[keep] ** 2)) / 2.0
    return NoiseEstimate(math.sqrt(noise2 + lsb ** 2 / 12.0), math.sqrt(noise2), lsb)


def noise_std(residual: np.ndarray, lsb_a: float | None = None) -> float:
    """Standard deviation of the noise model of a residual [A] (:func:`noise_estimate`)."""
    return noise_estimate(residual, lsb_a).std_a


@dataclass
class SensitivityReport:
    """Result of :func:`analyse_sensitivity`."""

    names: list[str]
    sensitivity_ma: dict[str, float]
    rel_std_pct: dict[str, float]
    ci95_pct: dict[str, float]
    pinned: list[str]
    not_pinned: list[str]
    weak_directions: list[dict[str, object]] = field(default_factory=list)
    noise_std_a: float = math.nan
    notes: list[str] = field(default_factory=list)
    derived: dict[str, object] = field(default_factory=dict)
    at_bound: list[str] = field(default_factory=list)
    inflation: float = 1.0
    #: Quantisation step of each quantised fit file [A] (by file name).
    current_lsb_a: dict[str, float] = field(default_factory=dict)
    #: Share of the noise variance that is quantisation (median over the files) [1].
    quantisation_share: float = 0.0

    def to_json(self) -> dict[str, object]:
        return {
            'noise_std_a': self.noise_std_a,
            'current_lsb_a': self.current_lsb_a,
            'quantisation_share_of_noise_variance': self.quantisation_share,
            'sensitivity_ma_per_pct': self.sensitivity_ma,
            'rel_std_pct': self.rel_std_pct,
            'ci95_pct': self.ci95_pct,
            'pinned_down': self.pinned,
            'not_pinned_down': self.not_pinned,
            'weak_directions': self.weak_directions,
            'derived': self.derived,
            'notes': self.notes,
            'at_search_bound': self.at_bound,
            'interval_inflation': self.inflation,
        }


def perturbed_values(space: ParameterSpace, params: ValveParameters, step: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Rows +-step (log) per free parameter, shape (2n, n), and each row pair's divisor.

    A parameter at 0 (an effect switched off) steps one-sidedly by ``step`` of its range.
    """
    vals = space.values_of(params)
    n = space.size
    rows = np.repeat(vals[None, :], 2 * n, axis=0)
    denom = np.full(n, 2.0 * step)
    for j, b in enumerate(space.bounds):
        v = vals[j]
        if v == 0.0:
            rows[2 * j, j] = step * (b.high - b.low)
            denom[j] = step
        else:
            rows[2 * j, j] = v * math.exp(step)
            rows[2 * j + 1, j] = v * math.exp(-step)
    return rows, denom


def file_jacobians(space: ParameterSpace, data: FitData, params: ValveParameters,
                   step: float = JACOBIAN_STEP) -> list[np.ndarray]:
    """d(current)/d(ln value) of each file, shape (n_samples, n_params), by central
    differences of ``step`` in the logarithm of each value (one batch of simulations); an
    infeasible step gives a zero column."""
    rows, denom = perturbed_values(space, params, step)
    raw = space.raw_from_values(rows)
    ok = space.feasible(raw)
    raw[~ok] = params.to_vector()
    n = space.size
    return [np.column_stack([(c[2 * j] - c[2 * j + 1]) / denom[j] for j in range(n)])
            for c, _ in data.simulate(raw)]


def current_jacobian(space: ParameterSpace, data: FitData, params: ValveParameters,
                     step: float = JACOBIAN_STEP) -> np.ndarray:
    """:func:`file_jacobians` of the valid samples, stacked over the files, shape
    (n_valid_samples, n_params)."""
    return np.vstack([jb[valid] for jb, valid in zip(file_jacobians(space, data, params, step),
                                                     data.valid)])


@dataclass
class _Information:
    """The Fisher information's eigen-decomposition and white-noise variances."""

    evals: np.ndarray
    evecs: np.ndarray
    null: np.ndarray
    var: np.ndarray


def _information(jac: np.ndarray, sigma: float) -> _Information:
    """Eigen-directions of ``F = J^T J / sigma^2``, those beyond _NULL_STD_PCT (``null``),
    and the white-noise variances of the relative parameters with them left out."""
    evals, evecs = np.linalg.eigh(jac.T @ jac / sigma ** 2)
    evals = np.maximum(evals, 0.0)
    std_dir = np.where(evals > 0, 100.0 / np.sqrt(np.maximum(evals, 1e-300)), np.inf)
    null = std_dir > _NULL_STD_PCT
    keep = ~null
    var = (evecs[:, keep] ** 2) @ (1.0 / evals[keep]) if keep.any() else np.zeros(jac.shape[1])
    return _Information(evals, evecs, null, var)


def _null_weight(info: _Information) -> np.ndarray:
    """Each parameter's weight in the directions the data cannot see."""
    if not info.null.any():
        return np.zeros(info.evecs.shape[0])
    return (info.evecs[:, info.null] ** 2).sum(axis=1)


def _white_variance(jac: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """White-noise variances of the relative parameters from ``jac`` at noise ``sigma``
    (directions beyond _NULL_STD_PCT left out), and which parameters have weight > 0.25 in
    such a direction."""
    info = _information(jac, sigma)
    return info.var, _null_weight(info) > 0.25


def _weak_directions(names: list[str], evals: np.ndarray, evecs: np.ndarray
                     ) -> list[dict[str, object]]:
    out = []
    for k in np.argsort(evals):
        lam = evals[k]
        std_pct = 100.0 / math.sqrt(lam) if lam > 0 else math.inf
        if 1.96 * std_pct < _PINNED_CI95_PCT:
            continue
        vec = evecs[:, k]
        vec = vec * np.sign(vec[np.argmax(np.abs(vec))])
        parts = [(names[j], float(vec[j])) for j in np.argsort(-np.abs(vec))
                 if abs(vec[j]) >= 0.2]
        text = ' * '.join(f'{PAPER_SYMBOLS.get(n, n)}^{w:+.2f}' for n, w in parts)
        out.append({'combination': text, 'components': dict(parts),
                    'rel_std_pct': std_pct if math.isfinite(std_pct) else None})
    return out


_GAP_GROUP = ('core_length_m', 'relative_permeability', 'total_air_gap_m')


def residual_inflation(residuals: list[np.ndarray], sigma: float) -> tuple[float, dict]:
    """Factor on white-noise standard errors for a structured, correlated residual.

    Two parts, multiplied: ``sqrt(mean r^2) / sigma`` (the residual is bigger than the
    noise: the model misses something, and the misfit acts as error) and
    ``sqrt((1 + rho) / (1 - rho))`` with ``rho`` the lag-1 autocorrelation of the residual
    (an AR(1) residual has that many fewer independent samples: its correlation time in
    samples). Each part is at least 1; ``rho`` is capped at 0.999.
    """
    r = np.concatenate([x[np.isfinite(x)] for x in residuals]) if residuals else np.zeros(0)
    if r.size < 4 or not math.isfinite(sigma) or sigma <= 0.0:
        return 1.0, {'size': 1.0, 'correlation': 1.0, 'lag1': None}
    size = max(1.0, math.sqrt(float(np.mean(r ** 2))) / sigma)
    rhos = []
    for x in residuals:
        x = x[np.isfinite(x)]
        if x.size > 4 and float(np.var(x)) > 0.0:
            x = x - x.mean()
            rhos.append(float(x[:-1] @ x[1:]) / float(x @ x))
    rho = min(max(float(np.median(rhos)) if rhos else 0.0, 0.0), 0.999)
    corr = math.sqrt((1.0 + rho) / (1.0 - rho))
    return size * corr, {'size': size, 'correlation': corr, 'lag1': rho}


def misfit_floor_pct(jac: np.ndarray, residuals: list[np.ndarray], sigma: float,
                     var_white: np.ndarray) -> tuple[np.ndarray, float]:
    """95 % interval floor [%] per parameter from the residual's structure, and its size [A].

    A model error is a bias, not noise: however many samples there are, a residual with
    ``r_s`` A RMS of structure beyond the noise can hold a parameter off its true value by
    the change that moves the current by ``r_s`` RMS (with the other parameters free to
    compensate). With ``M = J^T J / N`` that change is ``r_s sqrt((M^-1)_jj)``, i.e. the
    white-noise standard error ``sqrt(var_white_j)`` (at noise ``sigma``) times
    ``r_s sqrt(N) / sigma``. ``r_s^2 = mean(r^2) - sigma^2 (1 + 3 sqrt(2 / N))``: the
    noise's own sampling spread does not count as structure (clean data keep their
    intervals).

    Parameters
    ----------
    jac : numpy.ndarray, shape (N, n_params)
        Current sensitivities [A per unit relative change].
    residuals : list of numpy.ndarray
        Measured minus simulated current per file [A].
    sigma : float
        Noise standard deviation [A] (``var_white`` was computed with it).
    var_white : numpy.ndarray, shape (n_params,)
        White-noise variances of the relative parameters [1].
    """
    r = np.concatenate([x[np.isfinite(x)] for x in residuals]) if residuals else np.zeros(0)
    n = int(jac.shape[0])
    if r.size < 4 or n < 4 or not math.isfinite(sigma) or sigma <= 0.0:
        return np.zeros(len(var_white)), 0.0
    excess = float(np.mean(r ** 2)) - sigma ** 2 * (1.0 + 3.0 * math.sqrt(2.0 / r.size))
    if excess <= 0.0:
        return np.zeros(len(var_white)), 0.0
    r_s = math.sqrt(excess)
    std = np.sqrt(np.maximum(var_white, 0.0)) * r_s * math.sqrt(n) / sigma
    return 1.96 * 100.0 * std, r_s


def _median_variance(var: np.ndarray, extra: dict[float, np.ndarray], sigma: float
                     ) -> np.ndarray:
    """The median of the variances at the three steps: one step that lands on a jump (too
    tight) or on a plateau between jumps (too wide) does not decide; a column whose size
    changes with the step is flagged (:func:`_rough`) and never reported pinned down."""
    return np.median(np.vstack([var] + [np.where(n_x, 0.0, v_x) for v_x, n_x in
                                        (_white_variance(jx, sigma) for jx in extra.values())]),
                     axis=0)


def _rough(names: list[str], jac: np.ndarray, extra: dict[float, np.ndarray],
           notes: list[str]) -> list[str]:
    """Parameters whose sensitivity changes by more than _ROUGH_RATIO with the step (a
    note each is added to ``notes``)."""
    rough = []
    for j, n in enumerate(names):
        rms = [float(np.sqrt(np.mean(jx[:, j] ** 2))) for jx in (jac, *extra.values())]
        if min(rms) > 0.0 and max(rms) > _ROUGH_RATIO * min(rms):
            rough.append(n)
            notes_rough = ', '.join(f'{1e3 * r / 100.0:.3g}' for r in rms)
            notes.append(f'the current is not a smooth function of {PAPER_SYMBOLS.get(n, n)} '
                         f'here (mA per % at steps of {JACOBIAN_STEP:g}, '
                         + ', '.join(f'{x:g}' for x in _CHECK_STEPS) + f': {notes_rough}; '
                         'switching events of the drive electronics move): its interval '
                         'is the median of the three, and it is not reported pinned down')
    return rough


def _equivalent_gap(names: list[str], params: ValveParameters, rel_std: dict[str, float],
                    sens: dict[str, float | None], weak: list[dict[str, object]],
                    notes: list[str]) -> dict[str, object]:
    """With ``s`` among the free parameters: l_c, mu_r and x_t entered as not identifiable
    (in ``rel_std``, ``sens``, ``weak``, ``notes``) and ``s`` as a derived entry."""
    derived: dict[str, object] = {}
    if GAP not in names:
        return derived
    for n in _GAP_GROUP:
        rel_std[n] = math.inf
        sens[n] = None
    weak.insert(0, {'combination': 'l_c, mu_r, x_t at constant s = l_c/mu_r + 2 x_t',
                    'components': {n: None for n in _GAP_GROUP}, 'rel_std_pct': None})
    s_std = rel_std[GAP]
    derived['equivalent_gap'] = {
        'definition': 's = l_c / mu_r + 2 x_t', 'value_m': equivalent_gap_m(params),
        'rel_std_pct': s_std if math.isfinite(s_std) else None,
        'ci95_pct': None}  # set after the floors (the same as ci95_pct[s])
    notes.append('l_c, mu_r and x_t enter the model only through s = l_c/mu_r + 2 x_t '
                 '(eq. 4): no current measurement separates them. The search moves s; '
                 'l_c and x_t are held at their measured values and mu_r follows.')
    return derived


def _floored_intervals(rel_std: dict[str, float], names: list[str], jac: np.ndarray,
                       residuals: list[np.ndarray], sigma: float, var_white: np.ndarray,
                       nrmse_pct: float | None, notes: list[str]) -> dict[str, float]:
    """95 % half-widths [%]: ``1.96 rel_std``, floored by the residual's structure
    (:func:`misfit_floor_pct`) and, for a model that misses by more than
    _MISFIT_NRMSE_PCT of the range, by its NRMSE (it cannot pin anything tighter)."""
    ci95 = {n: 1.96 * v for n, v in rel_std.items()}
    floor, r_struct = misfit_floor_pct(jac, residuals, sigma, var_white)
    if r_struct > 0.0:
        for j, n in enumerate(names):
            if math.isfinite(ci95[n]) and floor[j] > ci95[n]:
                ci95[n] = float(floor[j])
        notes.append(f'the residual holds {1e3 * r_struct:.3g} mA RMS of structure beyond '
                     'the noise: no interval is narrower than the parameter change that '
                     'moves the current by that much (a misfit of that size can hide a '
                     'bias of that size; see misfit_floor_pct)')
    if nrmse_pct is not None and math.isfinite(nrmse_pct) and nrmse_pct > _MISFIT_NRMSE_PCT:
        ci95 = {n: max(v, nrmse_pct) for n, v in ci95.items()}
        notes.append(f'NRMSE {nrmse_pct:.3g} % > {_MISFIT_NRMSE_PCT:g} %: every interval is '
                     'at least the NRMSE')
    return ci95


def _quantisation_notes(data: FitData, noise: list[NoiseEstimate]) -> list[str]:
    """A note per quantised file: its LSB and the quantisation's share of the noise."""
    notes = []
    for m, e in zip(data.measurements, noise):
        if e.lsb_a > 0.0 and math.isfinite(e.std_a):
            notes.append(
                f'{m.name}: the current is quantised in steps of {1e3 * e.lsb_a:.3g} mA; the '
                f'noise model sigma^2 = noise^2 + LSB^2/12 = ({1e3 * e.noise_a:.3g} mA)^2 + '
                f'({1e3 * e.lsb_a / math.sqrt(12.0):.3g} mA)^2 gives sigma = '
                f'{1e3 * e.std_a:.3g} mA, at least {100 * e.quantisation_share:.0f} % of its '
                'variance quantisation (the noise is what the differences of the residual '
                'show, part of the rounding included); the intervals widen with it')
    return notes


def analyse_sensitivity(space: ParameterSpace, data: FitData, params: ValveParameters,
                        *, at_bound: list[str] | tuple[str, ...] = (),
                        nrmse_pct: float | None = None) -> SensitivityReport:
    """Local sensitivity and confidence analysis at ``params``.

    Parameters
    ----------
    space : ParameterSpace
        The free parameters (search coordinates, e.g. ``equivalent_gap_m``).
    data : FitData
        The fit files.
    params : ValveParameters
        The identified parameters.

    Returns
    -------
    SensitivityReport
        Entries for every search coordinate; when the space uses ``equivalent_gap_m``,
        also l_c, mu_r and x_t, reported as not identifiable on their own.
    """
    jac = current_jacobian(space, data, params)
    # The current through the drive electronics is not a smooth function of the
    # parameters (a chopper edge or the end of the boost moves by whole switching events),
    # so one finite-difference step can see a jump and claim a tight interval: the
    # Jacobian is also taken at a third and at three times that step.
    extra = {step: current_jacobian(space, data, params, step) for step in _CHECK_STEPS}
    residuals = data.residuals(params)
    noise = [noise_estimate(r, m.current_lsb_a) for m, r in zip(data.measurements, residuals)]
    sigma = float(np.nanmedian([e.std_a for e in noise])) if noise else math.nan
    names = list(space.names)
    sens = {n: float(np.sqrt(np.mean(jac[:, j] ** 2)) * 1e3 / 100.0)
            for j, n in enumerate(names)}
    notes = _quantisation_notes(data, noise)
    if not math.isfinite(sigma) or sigma <= 0.0:
        sigma = 1e-3
        notes.append('noise could not be estimated from the residual; 1 mA assumed')
    info = _information(jac, sigma)
    var = _median_variance(info.var, extra, sigma)
    rough = _rough(names, jac, extra, notes)
    # Structured/correlated residual: widen every interval (block of correlated samples
    # and misfit count as error), see residual_inflation.
    infl, infl_parts = residual_inflation(residuals, sigma)
    var = var * infl ** 2
    null_weight = _null_weight(info)
    rel_std = {n: (math.inf if null_weight[j] > 0.25 else 100.0 * math.sqrt(var[j]))
               for j, n in enumerate(names)}
    weak = _weak_directions(names, info.evals, info.evecs)
    derived = _equivalent_gap(names, params, rel_std, sens, weak, notes)
    if info.null.any():
        notes.append('parameters with weight in a direction the data cannot see are '
                     'reported without an error (not identifiable)')
    notes.append('confidence intervals are local (linearised), widened for the '
                 'residual\'s size and correlation')
    notes.append(f'intervals widened by {infl:.3g} for the residual (size '
                 f'{infl_parts["size"]:.3g} x correlation {infl_parts["correlation"]:.3g}, '
                 'see residual_inflation)')
    ci95 = _floored_intervals(rel_std, names, jac, residuals, sigma, var / infl ** 2,
                              nrmse_pct, notes)
    for n in at_bound:
        if n in ci95:
            notes.append(f'{PAPER_SYMBOLS.get(n, n)} sits at its search bound: a sign of '
                         'misfit; not reported as pinned down')
    if 'equivalent_gap' in derived:
        c = ci95.get(GAP, math.inf)
        derived['equivalent_gap']['ci95_pct'] = c if math.isfinite(c) else None
    pinned = [n for n in ci95 if ci95[n] < _PINNED_CI95_PCT and n not in at_bound
              and n not in rough]
    not_pinned = [n for n in ci95 if n not in pinned]
    return SensitivityReport(
        names=list(rel_std), sensitivity_ma=sens,
        rel_std_pct={k: (v if math.isfinite(v) else None) for k, v in rel_std.items()},
        ci95_pct={k: (v if math.isfinite(v) else None) for k, v in ci95.items()},
        pinned=pinned, not_pinned=not_pinned, weak_directions=weak, noise_std_a=sigma,
        notes=notes, derived=derived, at_bound=list(at_bound), inflation=infl,
        current_lsb_a={m.name: e.lsb_a for m, e in zip(data.measurements, noise)
                       if e.lsb_a > 0.0},
        quantisation_share=float(np.median([e.quantisation_share for e in noise]))
        if noise else 0.0)
