"""Benchmark the static duty map.

1. ``map_full_grid``: ``generate_map`` on the full grid (duty 0..100 % in 1 % steps x
   0/2/4/6 bar x 20/50/100/200 Hz = 1616 points), drive electronics on, every point to its
   periodic steady state, dead band and saturation edges bisected, in 2 worker processes
   (one per core; start-up of the workers included). Target <= 10 s on 2 cores.
   Reference, measured in the same run: a plain loop of single simulations
   (``simulate_pwm`` with its default 100 kHz output sampling, one call per point, each for
   exactly the number of periods the batch found that point needed, so the loop does no
   steady-state search at all). The loop runs on every 8th grid point and is extrapolated
   by simulated time. A second record compares with a lean loop (1 kHz output sampling,
   the least a single-run call can cost). A third (target <= 1.2 x) compares with
   the bare kernel over the same simulated spans, side by side in the same run: the
   compiled integrator advancing every grid point straight to the end of the periods it
   needed (no steady-state test, no per-period stop, no worker processes), on THREADS
   threads of a child process on the numba jit (whose call releases the GIL; the
   ahead-of-time module holds it), extrapolated from the grid's spans to
   everything the generator simulated (edge bisection included) by simulated time.
2. ``map_full_grid_refined``: the same with the adaptive refinement of steep segments
   (``valve_map``'s default), informative.
3. ``flow_to_duty_compute``: one flow -> duty computation of the node's inverter (eq. 12
   plus map inversion between grid pressures), mean over 200 000 random commands. Target
   <= 20 us. Reference: one scalar call of the model's numpy ``orifice_mass_flow``.

No timing is asserted in pytest; this script writes benchmarks/results/map.json.
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
from common import record as _record, write_results  # noqa: E402

HERE = Path(__file__).resolve().parent
THREADS = 2
PLAIN_STRIDE = 8
SIDE_BY_SIDE = 3


def _load_avg() -> str:
    try:
        return f'machine load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs'
    except OSError:
        return ''


def bench_grid(records: list[dict]) -> None:
    from valve_model_pkg.maps.generation import PAPER_GRID, generate_map
    from valve_model_pkg.model import ElectronicsConfig, load_parameters, simulate_pwm
    params = load_parameters()
    electronics = ElectronicsConfig()
    # warm the numba cache of this process for the plain loop (not part of either time)
    simulate_pwm(params, electronics, duty=0.5, pwm_frequency_hz=50.0, duration_s=0.04,
                 sample_rate_hz=1000.0)

    t0 = time.perf_counter()
    dmap, stats = generate_map(params, electronics, PAPER_GRID, refinement=None,
                               threads=THREADS)
    batch_s = time.perf_counter() - t0

    # plain loop on every PLAIN_STRIDE-th point, each for the periods it needed
    n_f, n_p, n_d = dmap.position_fraction.shape
    flat = [(i, j, k) for i in range(n_f) for j in range(n_p) for k in range(n_d)]
    subset = flat[::PLAIN_STRIDE]
    sim_all = float(sum(int(dmap.periods[i, j, k]) / float(dmap.pwm_frequencies_hz[i])
                        for i, j, k in flat))

    def plain_loop(sample_rate_hz: float) -> tuple[float, float]:
        sim_subset = 0.0
        t1 = time.perf_counter()
        for i, j, k in subset:
            f = float(dmap.pwm_frequencies_hz[i])
            n = int(dmap.periods[i, j, k])
            simulate_pwm(params, electronics, duty=float(dmap.duty[k]), pwm_frequency_hz=f,
                         duration_s=n / f + 1e-6, supply_pressure_pa=float(
                             dmap.supply_pressures_pa[j]), sample_rate_hz=sample_rate_hz)
            sim_subset += n / f
        subset_s = time.perf_counter() - t1
        return subset_s * sim_all / sim_subset, subset_s

    plain_s, plain_subset_s = plain_loop(100e3)
    lean_s, lean_subset_s = plain_loop(1e3)
    records.append(_record(
        'map_full_grid_vs_lean_loop', batch_s, 's',
        'plain loop of simulate_pwm at 1 kHz output sampling (extrapolated)', lean_s,
        'informative', None,
        f'{len(subset)} points in {lean_subset_s:.2f} s (one process, knowing each point\'s '
        f'period count in advance); the generator simulated {stats.simulated_s:.1f} s for '
        f'{sim_all:.1f} s needed by the grid points (edge bisection included); '
        f'{_load_avg()}', ratio=lean_s / batch_s))
    records.insert(len(records) - 1, _record(
        'map_full_grid', batch_s, 's', 'plain loop of simulate_pwm (extrapolated)', plain_s,
        '<= 10 s on 2 cores', batch_s <= 10.0,
        f'{PAPER_GRID.n_points} grid points to periodic steady state + edge bisection; '
        f'{stats.runs} points simulated, {stats.simulated_s:.1f} s of model time; '
        f'grid phase {stats.grid_wall_s:.2f} s, '
        f'edges {stats.refine_wall_s:.2f} s, worker start {stats.extra.get("startup_s", 0):.2f}'
        f' s; {stats.threads} worker processes; plain loop: {len(subset)} of {len(flat)} points '
        f'in {plain_subset_s:.2f} s, extrapolated by simulated time; ratio = speed-up; '
        f'{stats.unconverged} unconverged, {stats.subharmonic} sub-harmonic; '
        + '; '.join(dmap.notes[:2]) + '; ' + _load_avg(), ratio=plain_s / batch_s))

    # side by side: map and bare kernel alternate, the best of each is compared (the load
    # of this shared machine changes within seconds)
    kernel_walls = [_bare_kernel_s(dmap, params, electronics)]
    map_walls = [batch_s]
    for _ in range(SIDE_BY_SIDE - 1):
        t3 = time.perf_counter()
        generate_map(params, electronics, PAPER_GRID, refinement=None, threads=THREADS)
        map_walls.append(time.perf_counter() - t3)
        kernel_walls.append(_bare_kernel_s(dmap, params, electronics))
    kernel_grid_s = min(kernel_walls)
    kernel_s = kernel_grid_s * stats.simulated_s / sim_all
    map_s = min(map_walls)
    records.append(_record(
        'map_full_grid_vs_bare_kernel', map_s, 's',
        'bare kernel over the same simulated spans (same run, 2 threads)', kernel_s,
        '<= 1.2 x bare kernel', map_s <= 1.2 * kernel_s,
        f'best of {SIDE_BY_SIDE} alternating runs each: map (whole generate_map incl. worker '
        f'start) ' + ', '.join(f'{w:.2f}' for w in map_walls) + ' s; kernel for the '
        f'{sim_all:.1f} s of the grid points ' + ', '.join(f'{w:.2f}' for w in kernel_walls)
        + f' s, x {stats.simulated_s / sim_all:.3f} for the {stats.simulated_s:.1f} s the '
        f'generator simulated (edges included); first map run: worker start '
        f'{stats.extra.get("startup_s", 0):.2f} s, grid {stats.grid_wall_s:.2f} s, edges '
        f'{stats.refine_wall_s:.2f} s; {_load_avg()}'))

    t2 = time.perf_counter()
    dref, sref = generate_map(params, electronics, PAPER_GRID, threads=THREADS)
    refined_s = time.perf_counter() - t2
    records.append(_record(
        'map_full_grid_refined', refined_s, 's', 'map_full_grid', batch_s,
        'informative', None,
        f'valve_map default: grid + edge bisection + adaptive refinement; {sref.runs} runs; '
        f'model incidents: {"; ".join(n for n in dref.notes if "did not return" in n) or "none"}'
        f'; {_load_avg()}'))


def _bare_kernel_s(dmap, params, electronics) -> float:
    """Wall time of the compiled kernel run straight through every grid point's periods.

    Runs in a child process on the numba jit kernel (``VALVE_KERNEL_AOT_DIR=off``): its
    bank call releases the GIL, so the THREADS threads use THREADS cores. The ahead-of-time
    module (what a node loads) holds the GIL; with it the reference would run on one core
    and flatter the map 2x.
    """
    import subprocess
    import tempfile
    f = np.repeat(np.asarray(dmap.pwm_frequencies_hz, float),
                  dmap.position_fraction.shape[1] * dmap.position_fraction.shape[2])
    p = np.tile(np.repeat(np.asarray(dmap.supply_pressures_pa, float),
                          dmap.position_fraction.shape[2]), dmap.position_fraction.shape[0])
    d = np.tile(np.asarray(dmap.duty, float),
                dmap.position_fraction.shape[0] * dmap.position_fraction.shape[1])
    n = dmap.periods.reshape(-1).astype(float)
    # the generator's period ends: k periods + 1 ns (worker._PAST_BOUNDARY_S)
    t_end = n * (1.0 / f) + 1e-9
    with tempfile.TemporaryDirectory(prefix='bench_map_') as tmp:
        spans = Path(tmp) / 'spans.npz'
        np.savez(spans, f=f, p=p, d=d, t_end=t_end)
        out = subprocess.run([sys.executable, str(Path(__file__).resolve()), '--bare-kernel',
                              str(spans)], check=True, text=True, stdout=subprocess.PIPE,
                             env={**os.environ, 'VALVE_KERNEL_AOT_DIR': 'off'}).stdout
    return float(out.strip().splitlines()[-1])


def _bare_kernel_child(spans: str) -> float:
    """The child of :func:`_bare_kernel_s`: nominal valve, electronics on, jit kernel."""
    import threading

    from valve_model_pkg.model import ElectronicsConfig, load_parameters
    from valve_model_pkg.model.aot import backend
    from valve_model_pkg.model.bank import ValveBank
    if backend().name != 'jit':
        raise SystemExit(f'bench_map: the reference kernel is {backend().name}, not jit')
    z = np.load(spans)
    f, p, d, t_end = z['f'], z['p'], z['d'], z['t_end']
    params, electronics = load_parameters(), ElectronicsConfig()
    order = np.argsort(-t_end, kind='stable')
    chunks = [order[k::THREADS] for k in range(THREADS)]
    banks = [ValveBank(params, electronics, 24.0, n_valves=len(c), duty=d[c].tolist(),
                       pwm_frequency_hz=f[c].tolist(), supply_pressure_pa=p[c].tolist())
             for c in chunks]
    ValveBank(params, electronics, n_valves=1, duty=0.5).advance_to(0.01)  # loaded
    threads = [threading.Thread(target=b.advance_to, args=(t_end[c],))
               for b, c in zip(banks, chunks)]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return time.perf_counter() - t0


def bench_inversion(records: list[dict]) -> None:
    from valve_model_pkg.maps import FlowToDutyInverter, flow_per_opening, load_map
    from valve_model_pkg.model import load_parameters, orifice_mass_flow
    params = load_parameters()
    inv = FlowToDutyInverter(load_map(), 50.0)
    rng = np.random.default_rng(1)
    n = 200_000
    supply = rng.uniform(0.5e5, 6e5, n).tolist()
    output = rng.uniform(0.0, 3e5, n).tolist()
    flows = []
    for p_s, p_o in zip(supply, output):
        k, _ = flow_per_opening(p_s, p_o, inv.constants)
        flows.append(rng.uniform(0.0, 1.1) * k * params.stroke_m)
    compute = inv.compute
    t0 = time.perf_counter()
    for q, p_s, p_o in zip(flows, supply, output):
        compute(q, p_s, p_o)
    per_cmd_us = (time.perf_counter() - t0) / n * 1e6
    m = 20_000
    t1 = time.perf_counter()
    for q, p_s, p_o in zip(flows[:m], supply[:m], output[:m]):
        orifice_mass_flow(1e-4, p_s, p_o, params)
    ref_us = (time.perf_counter() - t1) / m * 1e6
    records.append(_record(
        'flow_to_duty_compute', per_cmd_us, 'us', 'model orifice_mass_flow, one scalar call',
        ref_us, '<= 20 us per command', per_cmd_us <= 20.0,
        f'FlowToDutyInverter.compute (what the node runs per command), 50 Hz shipped map, '
        f'{n} random commands: supply 0.5-6 bar (mostly between grid pressures), output '
        f'0-3 bar (choked and subsonic), flows 0-110 % of full; Python {sys.version.split()[0]}'
        f'; {_load_avg()}'))


def main() -> int:
    records: list[dict] = []
    bench_inversion(records)
    bench_grid(records)
    write_results('map', records)
    for r in records:
        print(f"{r['name']}: {r['value']:.4g} {r['unit']} (reference {r['reference_value']:.4g}"
              f", ratio {r['ratio']:.3g}, target {r['target']}, passed {r['passed']})")
    return 0


if __name__ == '__main__':
    if len(sys.argv) == 3 and sys.argv[1] == '--bare-kernel':
        print(_bare_kernel_child(sys.argv[2]))
        sys.exit(0)
    sys.exit(main())
