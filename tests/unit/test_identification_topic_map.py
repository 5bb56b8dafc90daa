"""Identification from a user's own topics: ``--map ROLE=TOPIC[.FIELD]``.

A bench record of the independent truth model (tests/datagen) is written as the bag a
user's firmware would leave (Float64 topics without header, a voltage published only when
it changes) and must read as the same record as its CSV; a user's telemetry type with a
header and a nested interval-mean current must read as the suite's own ValveState does;
bad mappings and bad bags are refused in one line (exit 2 from valve_identify).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from datagen.cache import dataset
from suite_bags import header, write_rosbag2
from valve_model_pkg.errors import MeasurementFormatError
from valve_model_pkg.identification.bag_reader import read_bag
from valve_model_pkg.identification.csv_reader import read_csv
from valve_model_pkg.identification.readers import read_measurements
from valve_model_pkg.identification.topic_map import parse_topic_map
from valve_model_pkg.recording import FieldSpec, build_typestore

START_NS = 1_700_000_000_000_000_000
STEP_MAP = ['voltage=/coil/voltage', 'current=/coil/current',
            'supply_pressure=/supply/pressure.fluid_pressure']
#: A user's drive telemetry: a header and the interval-mean current in a nested message.
COIL_MSG = 'float64 current_mean\nfloat64 voltage_mean\n'
TELEMETRY_MSG = 'std_msgs/Header header\nmy_drive/CoilMeans coil\nuint32 counter\n'


@pytest.fixture(scope='module')
def store():
    s = get_typestore(Stores.ROS2_JAZZY)
    s.register(get_types_from_msg(COIL_MSG, 'my_drive/msg/CoilMeans'))
    s.register(get_types_from_msg(TELEMETRY_MSG, 'my_drive/msg/Telemetry'))
    return s


@pytest.fixture(scope='module')
def records(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The truth model's bench step records (noise, missing values, gaps in t)."""
    return dataset(tmp_path_factory.mktemp('datagen'), 'none', seed=1)


def _step_bag(path: Path, store, csv: Path, *, storage: str = 'mcap') -> Path:
    """The record as a user's bag: the current at every sample, the voltage only when it
    changes, the supply pressure (gauge [Pa], in a sensor_msgs/FluidPressure with a
    header) once; all received at the sample instants."""
    m = read_csv(csv)
    t_ns = START_NS + np.round(m.t_s * 1e9).astype(np.int64)
    f64 = store.types['std_msgs/msg/Float64']
    pressure = store.types['sensor_msgs/msg/FluidPressure']
    msgs = []
    for k, ns in enumerate(t_ns):
        if k == 0 or m.voltage_v[k] != m.voltage_v[k - 1]:
            msgs.append(('/coil/voltage', 'std_msgs/msg/Float64', int(ns),
                         f64(data=float(m.voltage_v[k]))))
        msgs.append(('/coil/current', 'std_msgs/msg/Float64', int(ns),
                     f64(data=float(m.current_a[k]))))
        if k == 0:
            msgs.append(('/supply/pressure', 'sensor_msgs/msg/FluidPressure', int(ns),
                         pressure(header=header(store.types, int(ns)),
                                  fluid_pressure=m.supply_pressure_pa, variance=0.0)))
    return write_rosbag2(path, store, msgs, storage=storage)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_users_step_bag_reads_as_the_same_record_as_its_csv(
        tmp_path: Path, store, records: dict, storage: str) -> None:
    csv = Path(records['fit'][0])
    bag = _step_bag(tmp_path / 'bag', store, csv, storage=storage)
    (m,) = read_measurements([bag], mapping=parse_topic_map(STEP_MAP))
    ref = read_csv(csv)
    np.testing.assert_allclose(m.t_s, ref.t_s, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(m.voltage_v, ref.voltage_v)     # held between changes
    np.testing.assert_array_equal(m.current_a, ref.current_a)     # nan where missing
    assert m.n_missing_values == ref.n_missing_values > 0
    assert m.supply_pressure_pa == ref.supply_pressure_pa
    assert m.experiment == 'step' and m.sampling == 'instant' and m.drive is None
    notes = '\n'.join(m.notes)
    assert 'current from /coil/current.data (std_msgs/msg/Float64' in notes
    assert 'timed by the receive times (the type has no header)' in notes
    assert 'supply_pressure from /supply/pressure.fluid_pressure' in notes
    assert 'timed by its header stamps' in notes


def _valve_state_bag(path: Path) -> tuple[Path, np.ndarray]:
    """The suite's ValveState at 1 kHz running 50 Hz PWM (duty steps), interval means."""
    suite = build_typestore()
    state = suite.types['valve_msgs/msg/ValveState']
    n = 300
    k = np.arange(n)
    duty = np.where(k < 40, 0.0, np.where(k < 170, 0.4, 0.7))
    mean = np.where(duty > 0, 0.3 + 0.001 * (k % 20), 0.0)
    msgs = [('/valve/state', 'valve_msgs/msg/ValveState', START_NS + int(i) * 1_000_000 + 30,
             state(header=header(suite.types, START_NS + int(i) * 1_000_000, 'valve'),
                   sequence=int(i), coil_voltage=24.0 * (duty[i] > 0), coil_current=0.0,
                   coil_current_mean=float(mean[i]), coil_voltage_mean=0.0,
                   spool_position=0.0, spool_velocity=0.0, spool_position_avg=0.0,
                   mass_flow=0.0, duty=float(duty[i]), pwm_frequency=50.0,
                   supply_pressure=4e5, output_pressure=1e5, source=0,
                   position_measured=False)) for i in k]
    return write_rosbag2(path, suite, msgs), mean


def test_mapped_valve_state_fields_read_as_the_suite_reader_reads_them(tmp_path: Path) -> None:
    bag, mean = _valve_state_bag(tmp_path / 'bag')
    suite = read_bag(bag)
    mapped = read_bag(bag, mapping=parse_topic_map([
        'current_mean=/valve/state.coil_current_mean', 'duty=/valve/state.duty',
        'pwm_frequency=/valve/state.pwm_frequency', 'supply_voltage=24',
        'supply_pressure=/valve/state.supply_pressure',
        'output_pressure=/valve/state.output_pressure']))
    for m in (suite, mapped):
        assert m.experiment == 'operation' and m.sampling == 'interval_mean'
        np.testing.assert_array_equal(m.current_a, mean)
    # the suite's reader forms t from float epoch seconds (0.24 us), the mapped one from
    # ns; the period grid's phase is chosen among candidates period / 4000 apart
    np.testing.assert_allclose(mapped.t_s, suite.t_s, rtol=0, atol=1e-6)
    np.testing.assert_allclose(mapped.drive.period_starts_s, suite.drive.period_starts_s,
                               rtol=0, atol=1.0 / 50.0 / 4000 + 1e-9)
    np.testing.assert_array_equal(mapped.drive.period_duty, suite.drive.period_duty)
    assert (mapped.supply_pressure_pa, mapped.output_pressure_pa) == (4e5, 1e5)
    # starts at rest: compared from the first sample (time 0 is its interval's start)
    for m in (suite, mapped):
        assert m.exclude_before_s == m.t_s[0] > 0.0


def test_a_users_telemetry_type_and_a_command_topic_make_an_operation_record(
        tmp_path: Path, store) -> None:
    """Telemetry with a header and a nested interval-mean current at 1 kHz; the duty on a
    topic of its own, published only when it changes; the frequency a number."""
    tel = store.types['my_drive/msg/Telemetry']
    means = store.types['my_drive/msg/CoilMeans']
    f64 = store.types['std_msgs/msg/Float64']
    n = 300
    changes = {3: 0.0, 40: 0.4, 170: 0.7}   # sample -> duty published (received) then
    msgs = []
    for i in range(n):
        ns = START_NS + i * 1_000_000
        if i in changes:
            msgs.append(('/drive/duty', 'std_msgs/msg/Float64', ns - 200_000,
                         f64(data=changes[i])))
        msgs.append(('/drive/telemetry', 'my_drive/msg/Telemetry', ns + 80_000,
                     tel(header=header(store.types, ns), counter=i,
                         coil=means(current_mean=0.25 if i >= 40 else 0.0,
                                    voltage_mean=26.0 if i in (41, 171) else 12.0))))
    bag = write_rosbag2(tmp_path / 'bag', store, msgs, storage='sqlite3', split=2)
    m = read_bag(bag, mapping=parse_topic_map([
        'current_mean=/drive/telemetry.coil.current_mean', 'duty=/drive/duty',
        'pwm_frequency=50', 'coil_voltage_mean=/drive/telemetry.coil.voltage_mean',
        'supply_pressure=500000']))
    # the first telemetry stamp with a duty in force: sample 3 (duty received 0.2 ms before)
    assert m.n_samples == n - 3
    # time 0 is the start of the first sample's interval, one step before it
    np.testing.assert_allclose(m.t_s, np.arange(1, n - 2) * 1e-3, rtol=0, atol=1e-12)
    assert m.experiment == 'operation' and m.sampling == 'interval_mean'
    assert m.metadata['supply_voltage_v'] == '26'      # the largest interval-mean voltage
    starts = m.drive.period_starts_s[m.drive.period_duty > 0]
    assert 0.037 < starts[0] <= 0.038                   # duty 0.4 first seen at sample 40
    notes = '\n'.join(m.notes)
    assert 'the record starts at the first current_mean sample after the first message of ' \
        'duty (3 earlier samples left out)' in notes
    assert 'drive supply voltage 26 V' in notes
    assert 'current_mean from /drive/telemetry.coil.current_mean (my_drive/msg/Telemetry, ' \
        '300 messages), timed by its header stamps' in notes


@pytest.mark.parametrize('entries, expected', [
    (['current=/coil/current'], {'current': FieldSpec('/coil/current')}),
    (['duty=/valve/duty_command.duty', 'pwm_frequency=50', 'supply_pressure=4e5'],
     {'duty': FieldSpec('/valve/duty_command', 'duty'), 'pwm_frequency': 50.0,
      'supply_pressure': 4e5}),
])
def test_topic_maps(entries: list[str], expected: dict) -> None:
    assert parse_topic_map(entries) == expected


@pytest.mark.parametrize('entries, match', [
    (['current'], 'is not ROLE=TOPIC'),
    (['curent=/coil/current'], "unknown role 'curent'"),
    (['current=/a', 'current=/b'], "role 'current' is given twice"),
    (['current=5'], 'current must be a topic'),
    (['supply_pressure=nan'], 'must be a topic'),
    (['current=/coil current'], 'is not a topic name'),
])
def test_bad_topic_maps_are_refused_naming_the_entry(entries: list[str], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        parse_topic_map(entries)


@pytest.mark.parametrize('entries, match', [
    (['current=/coil/current', 'supply_pressure=4e5'], 'needs voltage .a step record. or '
                                                       'duty and pwm_frequency'),
    (['voltage=/coil/voltage'], 'needs exactly one of current'),
    (['current=/coil/current', 'duty=/coil/voltage'], 'no pwm_frequency'),
    (['voltage=/coil/voltage', 'current=/coil/current'], 'gives no supply_pressure'),
])
def test_mappings_that_make_no_record_are_refused(tmp_path: Path, store, records: dict,
                                                  entries: list[str], match: str) -> None:
    bag = _step_bag(tmp_path / 'bag', store, Path(records['validate'][0]))
    with pytest.raises(MeasurementFormatError, match=match) as info:
        read_bag(bag, mapping=parse_topic_map(entries))
    assert info.value.path == str(bag)


@pytest.mark.parametrize('entry, expected', [
    ('current=/coil/curent', "no topic /coil/curent for the current; the bag has "),
    ('current=/supply/pressure.pressure', "has no field 'pressure' for the current; its "
                                          'numeric fields: fluid_pressure'),
    ('current=/supply/pressure.header.frame_id', 'is text; expected a number per message'),
])
def test_valve_identify_refuses_a_bad_mapping_with_one_line_and_exit_2(
        tmp_path: Path, store, records: dict, capsys: pytest.CaptureFixture,
        entry: str, expected: str) -> None:
    from valve_model_pkg.cli.identify import main
    bag = _step_bag(tmp_path / 'bag', store, Path(records['validate'][0]))
    argv = ['--fit', str(bag), '-o', str(tmp_path / 'out'), '--quiet',
            '--map', 'voltage=/coil/voltage', '--map', entry,
            '--map', 'supply_pressure=/supply/pressure.fluid_pressure']
    assert main(argv) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f'valve_identify: error: {bag}: ')
    assert expected in lines[0]
    assert not (tmp_path / 'out').exists()


def test_valve_identify_refuses_a_malformed_map_as_a_usage_error(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from valve_model_pkg.cli.identify import main
    with pytest.raises(SystemExit) as info:
        main(['--fit', str(tmp_path), '-o', str(tmp_path / 'out'),
              '--map', 'current=/a', '--map', 'current=/b'])
    assert info.value.code == 2
    assert "--map 'current=/b': role 'current' is given twice" in capsys.readouterr().err


@pytest.mark.slow
def test_valve_identify_fits_a_users_bags(tmp_path: Path, store, records: dict) -> None:
    """--fit and --validate bags of a user's topics: the fit reaches the record's noise."""
    from valve_model_pkg.cli.identify import main
    fit = _step_bag(tmp_path / 'fit', store, Path(records['fit'][0]))
    val = _step_bag(tmp_path / 'val', store, Path(records['validate'][0]), storage='sqlite3')
    argv = ['--fit', str(fit), '--validate', str(val), '-o', str(tmp_path / 'out'),
            '--quick', '--no-diagnosis', '--no-plots', '--quiet']
    for entry in STEP_MAP:
        argv += ['--map', entry]
    assert main(argv) == 0
    report = json.loads((tmp_path / 'out' / 'report.json').read_text())
    noise_a = records['noise']['std_a']
    assert report['baseline']['validation']['rmse'] < 1.2 * noise_a
