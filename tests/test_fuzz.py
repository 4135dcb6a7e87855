"""Property-based fuzzing of every reader and decoder (issue 31; docs/testing.md, "Fuzzing").

The property, for each: the input is refused with a documented error (a :class:`KnodeError`
subclass naming the input; exit status 2 from a command, with its output file absent) or read
into a valid result; never another exception type, a hang or a partially written file.

Budgets come from the hypothesis profile (tests/conftest.py): ``suite`` (the default: a fixed
seed, a few dozen examples per reader, all of them together well under 60 s) or ``fuzz``
(``HYPOTHESIS_PROFILE=fuzz``, ``make fuzz``: 10,000 examples per reader). Every bug the fuzzer
found is kept as an ``@example`` of the test that found it.
"""

import contextlib
import copy
import functools
import io
import json
import math
import os
import struct
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from knode_swarm_ros.core.cli import parse_set
from knode_swarm_ros.core.errors import ConfigError, KnodeError
from knode_swarm_ros.core.policy_meta import PolicyError, check_meta, parse_meta, read_pt_meta
from knode_swarm_ros.core.trajectory import TrajectoryError, TrajectoryFile, load_trajectories
from knode_swarm_ros.nodes.common import conversions as cdr  # rclpy: required, never skipped

ROOT = Path(__file__).resolve().parents[1]
POLICIES = ROOT / 'knode_swarm_ros' / 'policies'
FUZZ = os.environ.get('HYPOTHESIS_PROFILE') == 'fuzz'


FUZZ_EXAMPLES = int(os.environ.get('FUZZ_EXAMPLES', '10000'))  # `make fuzz FUZZ_EXAMPLES=N`


def budget(suite: int):
    """``suite`` examples in the suite, FUZZ_EXAMPLES (10,000) under ``make fuzz`` (the profile's
    other settings)."""
    return settings(
        max_examples=FUZZ_EXAMPLES if FUZZ else suite,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
    )


# --- strategies shared by several readers ---------------------------------------------------------

SCENARIOS = ('flock2d', 'boids3d')
floats = st.floats(allow_nan=True, allow_infinity=True)
json_scalars = st.none() | st.booleans() | st.integers() | floats | st.text(max_size=20)
json_values = st.recursive(
    json_scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner, max_size=4),
    max_leaves=12,
)
# Text a hostile producer writes where JSON or YAML is expected: valid documents, near misses,
# bracket towers (a recursive parser's depth), huge numbers.
nested = st.integers(1, 2000).map(lambda n: '[' * n + ']' * n)
nested_yaml = st.integers(1, 600).map(lambda n: '[' * n)  # pyyaml recurses ~3 frames a level, slowly
huge_numbers = st.integers(300, 5000).map(lambda n: '1' + '0' * n)
# YAML's explicit tags on values that may not be of the tag (pyyaml's constructors once raised
# IndexError, KeyError or AttributeError on them), anchors and aliases (a list that holds itself).
YAML_TAGS = ['!!int', '!!float', '!!bool', '!!timestamp', '!!binary', '!!null', '!!str', '!!set', '!!map']
YAML_TAGS += ['!!seq', '!!omap', '!!pairs', '!!merge', '!!value', '!!python/none', '&a']
tagged_yaml = st.tuples(st.sampled_from(YAML_TAGS), st.sampled_from(['', ' ']), st.text(max_size=12)).map(
    ''.join
) | st.sampled_from(['&a [*a]', '&a {x: *a}', '[&a 1, *a, *b]', '<<: 1'])
hostile_text = st.one_of(
    st.text(max_size=200),
    json_values.map(lambda v: json.dumps(v)),
    nested,
    huge_numbers,
    st.sampled_from(['NaN', 'Infinity', '-Infinity', '{"a": NaN}', '"\\ud800"', '{', '[1,', '1e999']),
)


def _tmpdir():
    # In memory where there is /dev/shm: sqlite's fsync and the file churn of 10,000 examples
    # cost nothing there.
    return tempfile.TemporaryDirectory(
        prefix='knode-fuzz-', dir='/dev/shm' if os.path.isdir('/dev/shm') else None
    )


# --- CDR: Odometry and commands as they come off the wire ----------------------------------------


def _odom_bytes(endian, sec, nanosec, frame, child, pose, twist, tail_len):
    """A serialized Odometry with any stamp (int32 sec, uint32 nanosec), any frame ids and any
    pose and twist doubles, cut to ``tail_len`` bytes when given."""
    e = '<' if endian else '>'
    buf = bytearray(b'\x00\x01\x00\x00' if endian else b'\x00\x00\x00\x00')
    buf += struct.pack(e + 'iI', sec, nanosec)
    for text in (frame, child):
        raw = text.encode('utf-8', errors='surrogatepass') + b'\x00'
        buf += bytes((-(len(buf) - 4)) % 4)
        buf += struct.pack(e + 'I', len(raw)) + raw
    buf += bytes((-(len(buf) - 4)) % 8)
    buf += struct.pack(e + '7d', *pose) + bytes(8 * 36) + struct.pack(e + '6d', *twist) + bytes(8 * 36)
    return bytes(buf if tail_len is None else buf[:tail_len])


odom_bytes = st.builds(
    _odom_bytes,
    st.booleans(),
    st.integers(-(2**31), 2**31 - 1),
    st.integers(0, 2**32 - 1),
    st.text(max_size=40),
    st.text(max_size=40),
    st.tuples(*[floats] * 7),
    st.tuples(*[floats] * 6),
    st.none() | st.integers(0, 800),
)


def _check_odom(data, scenario):
    try:
        ns, child, z = cdr.odom_from_cdr(data, scenario)
    except cdr.CdrError:
        return
    assert isinstance(ns, int) and isinstance(child, str)
    assert z.dtype == np.float64 and z.shape == (cdr.get_scenario(scenario).state_dim,)


@budget(150)
@given(st.binary(max_size=1200) | odom_bytes, st.sampled_from(SCENARIOS))
def test_odometry_cdr_decodes_or_is_refused(data, scenario):
    _check_odom(data, scenario)


@budget(150)
@given(odom_bytes, st.integers(0, 799), st.integers(0, 255), st.sampled_from(SCENARIOS))
def test_odometry_cdr_with_a_flipped_byte_decodes_or_is_refused(data, at, byte, scenario):
    mutated = bytearray(data)
    if mutated:
        mutated[at % len(mutated)] = byte
    _check_odom(bytes(mutated), scenario)


def _command_bytes(encapsulation, sec, nanosec, frame_len, frame, u, tail_len):
    buf = bytearray(bytes([0, encapsulation, 0, 0]))
    buf += struct.pack('<iII', sec, nanosec, frame_len) + frame
    buf += bytes((-(len(buf) - 4)) % 8) + struct.pack('<6d', *u)
    return bytes(buf if tail_len is None else buf[:tail_len])


command_bytes = st.builds(
    _command_bytes,
    st.integers(0, 12),
    st.integers(-(2**31), 2**31 - 1),
    st.integers(0, 2**32 - 1),
    st.integers(0, 2**32 - 1) | st.integers(0, 12),
    st.binary(max_size=16),
    st.tuples(*[floats] * 6),
    st.none() | st.integers(0, 100),
)


@budget(150)
@given(st.binary(max_size=200) | command_bytes, st.sampled_from(SCENARIOS))
def test_command_cdr_decodes_or_is_refused(data, scenario):
    try:
        ns, u = cdr.command_from_cdr(data, scenario)
    except cdr.CdrError:
        return
    assert isinstance(ns, int) and u.dtype == np.float64
    assert u.shape == (cdr.get_scenario(scenario).command_dim,)


# --- trajectory files ------------------------------------------------------------------------------

dtypes = st.sampled_from(['<f8', '<f4', '<i8', '<u1', '|b1', '<c16', '<U8', '<M8[s]', '>f8'])
small_shapes = hnp.array_shapes(min_dims=0, max_dims=5, min_side=0, max_side=4)


@st.composite
def npz_fields(draw):
    """The fields of a trajectory file, each either plausible or hostile, or missing."""
    scenario = draw(st.sampled_from(SCENARIOS))
    d = {'flock2d': 4, 'boids3d': 6}[scenario]
    fields = {}
    if draw(st.integers(0, 9)):
        plausible = hnp.arrays(
            np.float64,
            st.tuples(
                st.integers(0, 2), st.integers(0, 3), st.integers(0, 3), st.sampled_from([d, d, 4, 6, 0])
            ),
            elements=st.floats(-1e6, 1e6) | floats,
        )
        fields['states'] = draw(plausible | hnp.arrays(dtypes, small_shapes))
    if draw(st.integers(0, 9)):
        fields['dt'] = draw(
            st.sampled_from([np.float64(0.05), np.float64(0.0), np.float64(-1.0), np.float64('nan')])
            | hnp.arrays(dtypes, small_shapes)
        )
    if draw(st.integers(0, 9)):
        fields['scenario'] = draw(
            st.sampled_from(SCENARIOS).map(np.str_)
            | st.text(max_size=12).map(np.str_)
            | hnp.arrays(dtypes, small_shapes)
        )
    if draw(st.integers(0, 9)):
        meta = st.fixed_dictionaries(
            {},
            optional={'split': st.dictionaries(st.sampled_from(['train', 'test']), json_values, max_size=2)},
        ).map(json.dumps)
        fields['meta'] = draw((meta | hostile_text).map(np.str_) | hnp.arrays(dtypes, small_shapes))
    return fields


def _check_trajectory(path):
    try:
        traj = load_trajectories(path)
    except TrajectoryError:
        return None
    assert isinstance(traj, TrajectoryFile)
    s = traj.states
    assert s.dtype == np.float64 and s.ndim == 4 and min(s.shape) >= 1 and np.all(np.isfinite(s))
    assert math.isfinite(traj.dt) and traj.dt > 0 and isinstance(traj.meta, dict)
    for name in ('train', 'test'):  # a file's split is read by training: valid indices
        idx = traj.split(name)
        assert idx.dtype == np.int64 and idx.ndim == 1 and np.all((0 <= idx) & (idx < s.shape[0]))
    return traj


@budget(100)
@given(npz_fields(), st.none() | st.floats(0, 1))
@example(
    {
        'states': np.zeros((1, 1, 1, 4)),
        'dt': np.float64(0.05),
        'scenario': np.str_('flock2d'),
        'meta': np.str_('[' * 2000 + ']' * 2000),
    },
    None,
)  # a bracket tower: json's recursion limit, once a RecursionError
@example(
    {
        'states': np.zeros((1, 1, 1, 4)),
        'dt': np.float64(0.05),
        'scenario': np.str_('flock2d'),
        'meta': np.str_('{"split": {"train": [5]}}'),
    },
    None,
)  # a split naming a trajectory the file does not hold
@example(
    {
        'states': np.zeros((1, 1, 1, 4)),
        'dt': np.float64(0.05),
        'scenario': np.str_('flock2d'),
        'meta': np.str_('{"split": {"train": "abc"}}'),
    },
    None,
)  # a split that is not a list of indices
def test_trajectory_files_load_or_are_refused(fields, cut):
    with _tmpdir() as tmp:
        path = Path(tmp) / 'traj.npz'
        np.savez(path, **fields)
        if cut is not None:
            data = path.read_bytes()
            path.write_bytes(data[: int(len(data) * cut)])
        _check_trajectory(path)


@budget(100)
@given(st.binary(max_size=2000), st.sampled_from([b'', b'PK\x03\x04', b'\x93NUMPY']))
def test_arbitrary_bytes_as_a_trajectory_file_are_refused(data, magic):
    with _tmpdir() as tmp:
        path = Path(tmp) / 'traj.npz'
        path.write_bytes(magic + data)
        _check_trajectory(path)


def test_an_npy_header_claiming_a_huge_array_is_refused_without_allocating_it():
    with _tmpdir() as tmp:
        path = Path(tmp) / 'traj.npz'
        np.savez(
            path,
            states=np.zeros((1, 1, 1, 4)),
            dt=np.float64(0.05),
            scenario=np.str_('flock2d'),
            meta=np.str_('{}'),
        )
        with zipfile.ZipFile(path) as src:
            members = {n: src.read(n) for n in src.namelist()}
        header = io.BytesIO()
        np.lib.format.write_array_header_1_0(
            header, {'descr': '<f8', 'fortran_order': False, 'shape': (10**4, 10**4, 10**3, 4)}
        )
        members['states.npy'] = header.getvalue() + bytes(64)
        with zipfile.ZipFile(path, 'w') as dst:
            for name, data in members.items():
                dst.writestr(name, data)
        with pytest.raises(TrajectoryError, match='states'):
            load_trajectories(path)


# .npy headers on which numpy's parser fails with something else than a ValueError: Python's
# tokenizer fails on one (a NUL byte, an unclosed bracket), sorting the keys on the other.
UNTOKENIZABLE_NPY = (
    b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fortran_order': False, 'shape': \x00), }" + b' ' * 62
)
UNTOKENIZABLE_NPY += b'\n' + bytes(8)
BYTES_KEY_NPY = b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fortran_order': False,B'shape': (), }" + b' ' * 62
BYTES_KEY_NPY += b'\n' + bytes(8)


@pytest.mark.parametrize('member', ['states', 'dt'])
@pytest.mark.parametrize('header', [UNTOKENIZABLE_NPY, BYTES_KEY_NPY], ids=['untokenizable', 'bytes-key'])
def test_an_npy_header_numpy_cannot_parse_is_refused(member, header):
    with _tmpdir() as tmp:
        path = Path(tmp) / 'traj.npz'
        fields = dict(states=np.zeros((1, 1, 1, 4)), dt=np.float64(0.05), scenario=np.str_('flock2d'))
        np.savez(path, meta=np.str_('{}'), **fields)
        with zipfile.ZipFile(path) as src:
            members = {n: src.read(n) for n in src.namelist()}
        members[f'{member}.npy'] = header  # once a tokenize.TokenError, a TypeError
        with zipfile.ZipFile(path, 'w') as dst:
            for name, data in members.items():
                dst.writestr(name, data)
        with pytest.raises(TrajectoryError, match='not a readable .npz trajectory file'):
            load_trajectories(path)


# --- policy files: knode.json, TorchScript, ONNX twins ---------------------------------------------


@functools.lru_cache(maxsize=None)
def _shipped_meta_cached(name):
    return read_pt_meta(POLICIES / f'{name}.pt')


def _shipped_meta(name='flock2d'):
    return copy.deepcopy(_shipped_meta_cached(name))


@st.composite
def hostile_meta(draw):
    """A shipped policy's knode.json with keys dropped, replaced by any JSON value, or added."""
    meta = dict(_shipped_meta(draw(st.sampled_from(SCENARIOS))))
    for key in draw(st.lists(st.sampled_from(sorted(meta)), max_size=3, unique=True)):
        if draw(st.booleans()):
            del meta[key]
        else:
            meta[key] = draw(json_values | st.integers(-(10**400), 10**400))
    meta.update(draw(st.dictionaries(st.text(max_size=8), json_values, max_size=2)))
    return meta


def _meta_text(meta):
    return json.dumps(meta)  # NaN and Infinity as json writes them (Python's json reads them back)


@budget(300)
@given(
    hostile_meta(),
    st.none() | st.dictionaries(st.sampled_from(['scenario', 'k', 'dt', 'tau']), json_values, max_size=2),
)
@example(dict(_shipped_meta(), d_cr=10**400), None)  # math.isfinite(a huge int): once an OverflowError
@example(_shipped_meta(), {'dt': 10**400})
def test_knode_json_is_checked_or_refused(meta, expect):
    try:
        check_meta('fuzz', parse_meta('fuzz', _meta_text(meta)), expect)
    except PolicyError:
        pass


@budget(300)
@given(hostile_text | st.binary(max_size=200))
@example('[' * 2000 + ']' * 2000)  # json's recursion limit: once a RecursionError
@example('1' + '0' * 4300)  # Python's int digit limit: once a ValueError
def test_knode_json_text_parses_or_is_refused(text):
    try:
        meta = parse_meta('fuzz', text)
    except PolicyError:
        return
    try:
        check_meta('fuzz', meta)
    except PolicyError:
        pass


@budget(30)
@given(st.binary(max_size=1000), st.sampled_from([b'', b'PK\x03\x04']))
def test_arbitrary_bytes_as_a_policy_file_are_refused(data, magic):
    from knode_swarm_ros.core.policy_runtime import load_runtime

    with _tmpdir() as tmp:
        pt = Path(tmp) / 'p.pt'
        pt.write_bytes(magic + data)
        for reader in (read_pt_meta, lambda p: load_runtime(p, 'torchscript')):
            with pytest.raises(PolicyError):
                reader(pt)


# The policy readers' properties are about their checks (knode.json, the probe, the twin's
# inputs, outputs and source), not about a network: each example carries its hostile metadata on
# a tiny module or model, built once, that the checks cannot tell from a trained one. Besides one
# that answers like a policy there are carriers the probe must refuse (a forward that raises for
# some k, a wrong shape or dtype, non-finite commands); the shipped files remain among them.


def _carrier_modules():
    """``{name: scripted module}``: tiny TorchScript policies of any ``d`` (command: the first
    ``d // 2`` state entries of row 0: the shipped scenarios' command sizes), and the shipped ones."""
    import torch

    class Answers(torch.nn.Module):
        def forward(self, Y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
            return Y[:, 0, : Y.shape[2] // 2] * mask[:, :1]

    class RaisesUnlessK6(torch.nn.Module):
        def forward(self, Y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
            if Y.shape[1] != 6:
                raise RuntimeError('this policy needs k = 6')
            return Y[:, 0, : Y.shape[2] // 2]

    class WrongShape(torch.nn.Module):
        def forward(self, Y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
            return Y[:, 0, :]

    class Float64(torch.nn.Module):
        def forward(self, Y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
            return Y[:, 0, : Y.shape[2] // 2].double()

    class NonFinite(torch.nn.Module):
        def forward(self, Y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
            return Y[:, 0, : Y.shape[2] // 2] / 0.0

    out = {
        cls.__name__: torch.jit.script(cls())
        for cls in (Answers, RaisesUnlessK6, WrongShape, Float64, NonFinite)
    }
    out.update({name: torch.jit.load(str(POLICIES / f'{name}.pt')) for name in SCENARIOS})
    return out


@pytest.fixture(scope='module')
def carriers():
    return _carrier_modules()


# A shipped module costs many times a tiny one to save and load: one example in eight carries on one.
carrier_names = st.sampled_from(
    ['Answers'] * 10 + ['RaisesUnlessK6', 'WrongShape', 'Float64', 'NonFinite', *SCENARIOS]
)


@budget(60)
@given(hostile_meta() | hostile_text, carrier_names)
def test_torchscript_with_a_hostile_knode_json_loads_or_is_refused(carriers, meta, carrier):
    import torch

    from knode_swarm_ros.core.policy_io import load_policy

    text = meta if isinstance(meta, str) else _meta_text(meta)
    with _tmpdir() as tmp:
        pt = Path(tmp) / 'p.pt'
        torch.jit.save(carriers[carrier], str(pt), _extra_files={'knode.json': text})
        try:
            policy = load_policy(pt)
        except PolicyError:
            return
        assert carrier in ('Answers', 'RaisesUnlessK6') + SCENARIOS, carrier  # the probe refuses the rest
        out = policy(np.zeros((1, policy.k, policy.meta['state_dim'])), np.ones((1, policy.k), dtype=bool))
        assert out.shape == (1, policy.meta['command_dim'])


def _onnx_carriers():
    """``{name: ModelProto}``: tiny ONNX policies (Y [batch, k, d], mask [batch, k] -> the first
    d // 2 entries of Y's row 0) with dynamic ``k`` and ``d``, with the shipped twin's fixed
    ``k`` and ``d``, and one that answers NaN; each with the shipped flock2d twin's metadata.
    And that twin itself."""
    import onnx
    from onnx import TensorProto, helper

    shipped = onnx.load(str(POLICIES / 'flock2d.onnx'))

    def const(name, values):
        return helper.make_node(
            'Constant', [], [name], value=helper.make_tensor(name, TensorProto.INT64, [len(values)], values)
        )

    def model(y_dims, nan=False):
        nodes = [
            const('two', [2]),
            const('zeros', [0, 0]),
            const('one', [1]),
            const('axes12', [1, 2]),
            helper.make_node('Shape', ['Y'], ['shape']),
            helper.make_node('Gather', ['shape', 'two'], ['d']),
            helper.make_node('Div', ['d', 'two'], ['half']),
            helper.make_node('Concat', ['one', 'half'], ['ends'], axis=0),
            helper.make_node('Slice', ['Y', 'zeros', 'ends', 'axes12'], ['row0']),
            helper.make_node('Squeeze', ['row0', 'one'], ['u0']),
            helper.make_node('ReduceSum', ['mask', 'one'], ['heard'], keepdims=1),
            helper.make_node('Mul', ['u0', 'heard'], ['u1']),
        ]
        if nan:
            nodes += [
                helper.make_node('Sub', ['u1', 'u1'], ['zero']),
                helper.make_node('Div', ['zero', 'zero'], ['u']),
            ]
        else:
            nodes += [helper.make_node('Identity', ['u1'], ['u'])]
        graph = helper.make_graph(
            nodes,
            'carrier',
            [
                helper.make_tensor_value_info('Y', TensorProto.FLOAT, ['batch', *y_dims]),
                helper.make_tensor_value_info('mask', TensorProto.FLOAT, ['batch', y_dims[0]]),
            ],
            [helper.make_tensor_value_info('u', TensorProto.FLOAT, ['batch', 'm'])],
        )
        out = helper.make_model(graph, opset_imports=[helper.make_opsetid('', 17)], ir_version=8)
        for prop in shipped.metadata_props:
            out.metadata_props.add(key=prop.key, value=prop.value)
        return out

    fixed = [d.dim_value for d in shipped.graph.input[0].type.tensor_type.shape.dim[1:]]
    return {
        'dynamic': model(['k', 'd']),
        'fixed': model(fixed),
        'nan': model(['k', 'd'], nan=True),
        'shipped': shipped,
    }


@pytest.fixture(scope='module')
def onnx_carriers():
    return {name: model.SerializeToString() for name, model in _onnx_carriers().items()}


@budget(60)
@given(
    hostile_meta() | hostile_text,
    st.booleans(),
    st.none() | st.text(max_size=64),
    st.booleans(),
    st.sampled_from(['dynamic'] * 5 + ['fixed', 'nan', 'shipped']),  # the shipped twin: one in eight
)
def test_an_onnx_twin_whose_metadata_disagree_is_refused(
    onnx_carriers, meta, with_pt, source, keep_source, carrier
):
    import onnx

    from knode_swarm_ros.core.policy_runtime import META_KEY, SOURCE_KEY, load_onnx_policy

    model = onnx.ModelProto.FromString(onnx_carriers[carrier])
    props = {p.key: p.value for p in model.metadata_props}
    props[META_KEY] = meta if isinstance(meta, str) else _meta_text(meta)
    if not keep_source:
        if source is None:
            props.pop(SOURCE_KEY, None)
        else:
            props[SOURCE_KEY] = source
    del model.metadata_props[:]
    for key, value in props.items():
        model.metadata_props.add(key=key, value=value)
    with _tmpdir() as tmp:
        twin = Path(tmp) / 'flock2d.onnx'
        twin.write_bytes(model.SerializeToString())
        pt = None
        if with_pt:
            pt = Path(tmp) / 'flock2d.pt'
            pt.write_bytes(SHIPPED_PT)
        try:
            policy = load_onnx_policy(twin, pt_path=pt)
        except PolicyError:
            return
        assert carrier != 'nan'  # the probe refuses non-finite commands
        assert policy.meta == (read_pt_meta(pt) if pt else policy.meta)
        d, m = policy.meta['state_dim'], policy.meta['command_dim']
        out = policy(np.zeros((1, policy.k, d)), np.ones((1, policy.k), dtype=bool))
        assert out.shape == (1, m) and np.all(np.isfinite(out))


SHIPPED_PT = (POLICIES / 'flock2d.pt').read_bytes()


# --- bags ---------------------------------------------------------------------------------------------


def _write_bag(bag, storage, stamps, values, type_name='nav_msgs/msg/Odometry'):
    """A rosbag2 directory (``storage`` mcap | sqlite3) of two robots' messages of ``type_name``,
    message j with the state ``values`` shifted by j, written in list order with the stamps
    ``stamps`` (header and log time alike)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from knode_swarm_ros.bag.messages import ns_to_stamp, to_message, typestore

    store = typestore()  # built once (a few hundred message types)
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with Writer(bag, version=9, storage_plugin=plugin) as writer:
        conns = [writer.add_connection(f'/robot_{i}/odom', type_name, typestore=store) for i in range(2)]
        for j, ns in enumerate(stamps):
            header = {'stamp': ns_to_stamp(ns), 'frame_id': 'world'}
            position = dict(zip('xyz', (values[0] + j // 2, values[1], values[2])))
            pose = {'position': position, 'orientation': {'w': values[3]}}
            value = {
                'nav_msgs/msg/Odometry': {'header': header, 'child_frame_id': 'r', 'pose': {'pose': pose}},
                'geometry_msgs/msg/PoseStamped': {'header': header, 'pose': pose},
                'std_msgs/msg/String': {'data': str(values)},
            }[type_name]
            writer.write(
                conns[j % 2], ns, store.serialize_cdr(to_message(type_name, value, store), type_name)
            )
    return bag


@pytest.fixture(scope='module')
def good_bags(tmp_path_factory):
    """``{suffix: bytes}`` of the storage file of a small valid bag of each storage (2 robots,
    20 frames at 20 Hz)."""
    stamps = [10**9 + 50_000_000 * (j // 2) for j in range(40)]
    out = {}
    for storage in ('mcap', 'sqlite3'):
        bag = _write_bag(tmp_path_factory.mktemp('bags') / storage, storage, stamps, [0.0, 0.0, 0.0, 1.0])
        (storage_file,) = [p for p in bag.iterdir() if p.suffix in ('.mcap', '.db3')]
        out[storage_file.suffix] = storage_file.read_bytes()
    return out


def _import(bag, out):
    from training.import_bag import main

    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        rc = main(
            [
                str(bag),
                '--scenario',
                'flock2d',
                '--topics',
                '/robot_*/odom',
                '--rate',
                '20',
                '--out',
                str(out),
            ]
        )
    assert rc in (0, 2), rc
    if rc == 2:
        assert not out.exists(), 'a refused bag left an output file'
    else:
        _check_trajectory(out)


@budget(40)
@given(
    st.sampled_from(['.mcap', '.db3']),
    st.one_of(
        st.tuples(st.just('truncate'), st.floats(0, 1)),
        st.tuples(
            st.just('flip'), st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=8)
        ),
        st.tuples(st.just('magic'), st.binary(max_size=600)),
    ),
)
@example(
    '.mcap',
    (
        'flip',
        [
            (0.6411184879684554, 0),
            (0.30579966380833473, 0),
            (0.008268541941080622, 0),
            (0.10583507450575483, 0),
        ]
        + [(0.008730982732846561, 0), (0.9806070630133557, 68)],
    ),
)  # a damaged definition of Odometry in the bag: once an AttributeError
def test_a_damaged_bag_imports_or_is_refused_without_writing(good_bags, suffix, damage):
    data = bytearray(good_bags[suffix])
    how, arg = damage
    if how == 'truncate':
        data = data[: int(len(data) * arg)]
    elif how == 'flip':
        for where, byte in arg:
            data[min(int(where * len(data)), len(data) - 1)] = byte
    else:
        magic = {'.mcap': b'\x89MCAP0\r\n', '.db3': b'SQLite format 3\x00'}[suffix]
        data = bytearray(magic + arg)
    with _tmpdir() as tmp:
        bag = Path(tmp) / f'run{suffix}'
        bag.write_bytes(bytes(data))
        _import(bag, Path(tmp) / 'out.npz')


@budget(15)
@given(
    st.lists(st.integers(0, 10**12), min_size=1, max_size=30),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=4, max_size=4),
    st.sampled_from(['nav_msgs/msg/Odometry', 'geometry_msgs/msg/PoseStamped', 'std_msgs/msg/String']),
    st.sampled_from(['mcap', 'sqlite3']),
)
@example(
    [0, 59, 0, 27758, 0, 648, 48084, 0],
    [4.677605422298023e225, 0.0, 0.0, 0.0],
    'nav_msgs/msg/Odometry',
    'mcap',
)  # the smoother squared 1e225 m: once an OverflowError
def test_bags_with_reordered_stamps_or_wrong_types_import_or_are_refused(stamps, values, type_name, storage):
    with _tmpdir() as tmp:
        bag = _write_bag(Path(tmp) / 'bag', storage, stamps, values, type_name)
        _import(bag, Path(tmp) / 'out.npz')


# --- track files (training.import_tracks): CSV and .npy -------------------------------------------

TRACK_COLUMNS = [
    't',
    'id',
    'x',
    'y',
    'z',
    'vx',
    'vy',
    'vz',
    'hx',
    'hy',
    'hz',
    'frame',
    ' T ',
    'ID',
    'x',
    '',
    'é',
]
# What a cell of a damaged CSV holds: a plausible number or something else.
hostile_cells = st.one_of(
    st.sampled_from(['nan', 'inf', '-inf', 'NaN', '1e308', '1e400', '-1e30', '1e30', '4.6e9', '9.3e9', '']),
    st.sampled_from(
        ['9223372036854775807', '9223372036854775808', '9007199254740993', '1_000', '３', '0x10']
    ),
    st.sampled_from(['abc', '1,5', '"', '"1"', '\x00', '\ufeff1', ' 2 ', '1e-320']),
    st.text(max_size=8),
    st.integers().map(str),
    floats.map(repr),
)


@st.composite
def track_csv(draw):
    """A CSV track file: plausible (the columns a scenario reads, robots sampled at jittered,
    possibly duplicated and shuffled times), then damaged: cells replaced, rows cut or lengthened,
    a header made up or dropped; or arbitrary text. With the scenario it is imported for."""
    scenario = draw(st.sampled_from(SCENARIOS))
    if draw(st.integers(0, 9)) == 0:
        return draw(st.text(max_size=300)), scenario
    dims = (
        {'flock2d': 2, 'boids3d': 3}[scenario] if draw(st.integers(0, 4)) else draw(st.sampled_from([2, 3]))
    )
    header = ['t', 'id', *'xyz'[:dims]]
    header += draw(st.sampled_from([[], ['v' + a for a in 'xyz'[:dims]], ['h' + a for a in 'xyz'[:dims]]]))
    if draw(st.integers(0, 3)) == 0:
        header = draw(st.lists(st.sampled_from(TRACK_COLUMNS) | st.text(max_size=5), max_size=8))
    robots = draw(st.integers(1, 4))
    frames = draw(st.integers(0, 40))
    step = draw(st.sampled_from([0.01, 0.05, 0.1, 0.1, 1.0, 1e-9, 1e6]))
    rows = []
    for k in range(frames):
        for r in range(robots):
            t = k * step + draw(st.sampled_from([0.0, 0.0, 0.0, step / 3, -step / 3]))
            row = [repr(t), str(r)] + [repr(draw(st.floats(-50, 50))) for _ in header[2:]]
            rows.append(row[: len(header)] + [''] * (len(header) - len(row)))
    if rows and draw(st.booleans()):
        rows += draw(st.lists(st.sampled_from(rows), max_size=5))  # duplicate (t, id) rows
        rows = draw(st.permutations(rows))
    for _ in range(draw(st.sampled_from([0, 0, 0, 1, 2, 4]))):
        if not rows:
            break
        row = list(draw(st.sampled_from(rows)))
        how = draw(st.integers(0, 3))
        if how == 0 and row:
            row[draw(st.integers(0, len(row) - 1))] = draw(hostile_cells)
        elif how == 1:
            row = row[: draw(st.integers(0, len(row)))]
        elif how == 2:
            row.append(draw(hostile_cells))
        rows.append(row)
    lines = [','.join(header)] if draw(st.integers(0, 9)) else []
    lines += [','.join(row) for row in rows]
    text = '\n'.join(lines) + draw(st.sampled_from(['', '\n', '\r\n']))
    return draw(st.sampled_from(['', '', '\ufeff'])) + text, scenario


@st.composite
def hostile_npy(draw):
    """An .npy file's bytes: an array of any dtype and shape (positions [T, n, dim] most often,
    with NaN/inf/huge values), a header declaring another shape, dtype or order than its data
    (terabytes among them), a cut file, an .npz archive, a pickle, or arbitrary bytes. With the
    scenario it is imported for."""
    scenario = draw(st.sampled_from(SCENARIOS))
    return draw(_npy_payload({'flock2d': 2, 'boids3d': 3}[scenario])), scenario


@st.composite
def _npy_payload(draw, dims):
    kind = draw(st.integers(0, 9))
    if kind == 0:
        return draw(st.sampled_from([b'', b'\x93NUMPY', b'PK\x03\x04'])) + draw(st.binary(max_size=300))
    if kind == 1:  # a header of its own, followed by some data
        descr = draw(
            st.sampled_from(['<f8', '>f4', '<i2', '|u1', '|b1', '<c16', '|O', '<U3', '|V8', 'float64'])
        )
        shape = draw(
            st.tuples()
            | st.lists(st.integers(0, 10**6) | st.sampled_from([10**12, 2**62, 0, 1]), max_size=4).map(tuple)
        )
        head = {'descr': descr, 'fortran_order': draw(st.booleans()), 'shape': shape}
        text = (
            repr(head) if draw(st.integers(0, 4)) else draw(hostile_text | st.sampled_from(["{'descr': 1}"]))
        )
        header = text.encode('latin1', 'replace')
        header += b' ' * (-(len(header) + 11) % 64) + b'\n'
        version = draw(st.sampled_from([b'\x01\x00', b'\x02\x00', b'\x03\x00', b'\x09\x09']))
        length = struct.pack('<H' if version == b'\x01\x00' else '<I', len(header) % 65536)
        return b'\x93NUMPY' + version + length + header + draw(st.binary(max_size=200))
    if kind == 2:
        return _npy_bytes(np.zeros((3, 2, 2)), npz=True)
    buf = io.BytesIO()
    if kind == 3:
        np.save(buf, np.array([{'trajectories': 1}, None], dtype=object), allow_pickle=True)
        return buf.getvalue()
    if draw(st.integers(0, 3)) == 0:
        arr = draw(hnp.arrays(dtypes, small_shapes))
    else:  # positions [T, n, dims] (mostly), a few of them NaN, inf or huge, of some numeric dtype
        dim = dims if draw(st.integers(0, 4)) else draw(st.sampled_from([1, 2, 3, 4]))
        shape = st.tuples(st.integers(0, 40), st.integers(0, 4), st.just(dim))
        arr = draw(hnp.arrays(np.float64, shape, elements=st.floats(-100, 100)))
        for _ in range(draw(st.sampled_from([0, 0, 0, 1, 3]))):
            if arr.size:
                arr.flat[draw(st.integers(0, arr.size - 1))] = draw(st.sampled_from([np.nan, np.inf, 1e300]))
        cast = [np.float64, np.float64, np.float32, np.float16, np.int64, np.uint8, np.dtype('>f8')]
        with np.errstate(all='ignore'):  # any data: a cast's garbage too
            arr = arr.astype(draw(st.sampled_from(cast)))
    np.save(buf, arr, allow_pickle=False)
    data = buf.getvalue()
    if draw(st.integers(0, 4)) == 0:  # cut, or a byte overwritten
        at = draw(st.integers(0, len(data)))
        data = (
            data[:at]
            if draw(st.booleans())
            else data[:at] + bytes([draw(st.integers(0, 255))]) + data[at + 1 :]
        )
    return data


def _npy_bytes(arr, npz=False, shape=None):
    """``arr`` saved as .npy (or .npz) bytes; with ``shape``, a float64 header declaring it and
    64 bytes of data."""
    buf = io.BytesIO()
    if shape is not None:
        np.lib.format.write_array_header_1_0(buf, {'descr': '<f8', 'fortran_order': False, 'shape': shape})
        return buf.getvalue() + bytes(64)
    (np.savez if npz else np.save)(buf, arr)
    return buf.getvalue()


fps_values = st.sampled_from(
    ['30'] * 4
    + ['10', '1', '0.5', '1e-300', '5e-324', '1e300', '1e-9', '0', '-30', 'nan', 'inf', '-inf', 'x', None]
)
# Resample options with which short files make trajectories (the default keeps segments of 1 s).
track_options = st.sampled_from(
    [
        [],
        ['--min-duration', '0'],
        ['--min-duration', '0', '--smooth', 'none'],
        ['--min-duration', '0.1', '--max-gap', '0.3'],
        ['--min-duration', '0', '--length', '3', '--test-trajectories', '1'],
    ]
)


def _import_tracks(name, data, scenario, fps=None, options=()):
    """``training.import_tracks`` on one file: exit 2 with a message naming the file (or the bad
    option) and nothing written (the output and its temporary file absent), or 0 with a trajectory
    file that loads."""
    from training.import_tracks import main

    with _tmpdir() as tmp:
        path = Path(tmp) / name
        path.write_bytes(data)
        out = Path(tmp) / 'out.npz'
        argv = [str(path), '--scenario', scenario, '--out', str(out), *options]
        argv += [f'--fps={fps}'] if fps else []
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                rc = main(argv)
            except SystemExit as exc:  # argparse: a bad option
                rc = exc.code
        assert rc in (0, 2), (rc, err.getvalue())
        assert 'Traceback' not in err.getvalue()
        if rc == 2:
            assert sorted(os.listdir(tmp)) == [name], 'a refused track file left an output'
            assert f'error: {path}' in err.getvalue() or 'error: argument --fps' in err.getvalue(), (
                err.getvalue()
            )
        else:
            assert sorted(os.listdir(tmp)) == sorted([name, 'out.npz'])
            traj = _check_trajectory(out)
            assert traj is not None and traj.scenario == scenario


@budget(100)
@given(track_csv(), st.sampled_from([None] * 7 + ['30']), track_options)
@example(('t,id,x,y\n0,1e30,0,0\n0.1,1e30,1,1\n', 'flock2d'), None, [])  # once an OverflowError (int64 ids)
@example(('t,id,x,y\n0,0,0,0\n1e6,0,1,1\n2e6,0,2,2\n', 'flock2d'), None, [])  # 2e8 frames: once out of memory
@example(
    ('t,id,x,y\n0.0,0,0.0,0.0\n0.01,0,0.0,0.0', 'flock2d'), None, []
)  # the smoother on 2 samples: once a LinAlgError
def test_csv_track_files_import_or_are_refused_without_writing(csv_file, fps, options):
    text, scenario = csv_file
    _import_tracks('tracks.csv', text.encode('utf-8', 'surrogatepass'), scenario, fps, options)


@budget(30)
@given(st.binary(max_size=600), st.sampled_from(['tracks.csv', 'tracks.txt', 'tracks.dat']))
def test_arbitrary_bytes_as_a_track_file_import_or_are_refused(data, name):
    _import_tracks(name, data, 'flock2d')


@budget(100)
@given(hostile_npy(), fps_values, track_options)
@example((b'', 'flock2d'), '30', [])  # once an EOFError
@example((_npy_bytes(np.zeros((3, 2, 2)), npz=True), 'flock2d'), '30', [])  # once an AttributeError
@example((_npy_bytes(None, shape=(10**6, 10**6, 2)), 'flock2d'), '30', [])  # 14.6 TiB: once a MemoryError
@example((UNTOKENIZABLE_NPY, 'flock2d'), '30', [])  # once a tokenize.TokenError from numpy
@example((BYTES_KEY_NPY, 'flock2d'), '30', [])  # once a TypeError from numpy
def test_npy_track_files_import_or_are_refused_without_writing(npy_file, fps, options):
    data, scenario = npy_file
    _import_tracks('tracks.npy', data, scenario, fps, options)


# --- training configs and --set values ----------------------------------------------------------------

CONFIGS = sorted((ROOT / 'config').glob('train_*.yaml'))


@functools.lru_cache(maxsize=None)
def _yaml_doc(path):
    """A shipped YAML file's document, read once (each example mutates a copy)."""
    return yaml.safe_load(path.read_text())


@st.composite
def hostile_config(draw):
    """A shipped training config with leaves replaced by any YAML value, sections dropped or
    replaced by scalars, or not a mapping at all."""
    raw = copy.deepcopy(_yaml_doc(draw(st.sampled_from(CONFIGS))))
    for _ in range(draw(st.integers(0, 4))):
        section = draw(st.sampled_from(sorted(raw)))
        if isinstance(raw[section], dict) and raw[section] and draw(st.booleans()):
            key = draw(st.sampled_from(sorted(raw[section])))
            raw[section][key] = draw(json_values)
        elif draw(st.booleans()):
            del raw[section]
        else:
            raw[section] = draw(json_values)
        if not raw:
            break
    return draw(st.just(raw) | json_values)


set_items = st.one_of(
    st.text(max_size=30),
    st.tuples(
        st.sampled_from(
            ['training.epochs', 'policy.k', 'policy', 'data.stride', 'noise.mode', 'x.y.z', '.', 'seed.x']
        ),
        st.text(max_size=20)
        | tagged_yaml
        | json_values.map(lambda v: yaml.safe_dump(v, default_flow_style=True).strip()),
    ).map('='.join),
)


@budget(40)
@given(
    hostile_config(),
    st.lists(set_items, max_size=3),
    st.just('') | tagged_yaml.map(lambda t: f'\nseed: {t}\n'),  # a line yaml.safe_dump never writes
)
@example(
    {'scenario': 'flock2d'}, ['policy=3', 'policy.k=4'], ''
)  # a --set below a scalar: once an AttributeError
@example([1, 2], ['policy.k=4'], '')  # a config that is not a mapping
@example({'scenario': 'auto', 'policy': {'k': 'auto'}}, ['policy=1'], '')  # auto fields of no mapping
@example({'scenario': 'flock2d'}, ['training.epochs=!!float'], '')  # pyyaml: once an IndexError
@example({'scenario': 'flock2d'}, [], '\nseed: !!bool maybe\n')  # and a KeyError
@example({'scenario': 'flock2d'}, ['policy=&a {k: *a}'], '')  # a mapping that holds itself
@example({'scenario': 'flock2d'}, ['training.objective=[]'], '')  # `in` a dict: once a TypeError
def test_training_configs_and_set_values_load_or_are_refused(raw, items, line):
    from training.learning.config import PendingConfig, load_config

    with _tmpdir() as tmp:
        path = Path(tmp) / 'train.yaml'
        path.write_text(yaml.safe_dump(raw) + line)
        try:
            cfg = load_config(str(path), parse_set(items))
        except ConfigError:
            return
        if isinstance(cfg, PendingConfig):  # fields the data decide (``auto``): validated but those
            assert cfg.auto or cfg.raw.get('scenario') == 'auto'
            return
        assert isinstance(cfg, dict) and cfg['scenario'] in SCENARIOS


@budget(60)
@given(
    st.lists(
        st.text(max_size=40) | (nested_yaml | huge_numbers | tagged_yaml).map(lambda t: 'a.b=' + t),
        max_size=4,
    )
)
@example(['a=' + '[' * 600])  # yaml's recursion: once a RecursionError
@example(['a=1' + '0' * 4300])  # Python's int digit limit: once a ValueError
@example(['a=!!int'])  # pyyaml's constructors: once an IndexError,
@example(['a=!!bool maybe'])  # a KeyError,
@example(['a=!!timestamp soon'])  # an AttributeError
def test_set_values_parse_or_are_refused(items):
    try:
        out = parse_set(items)
    except ConfigError:
        return
    assert isinstance(out, dict)


# --- scenario and fleet files ---------------------------------------------------------------------

SCENARIO_FILES = sorted((ROOT / 'knode_swarm_ros' / 'scenarios').glob('*.yaml'))
FLEET_FILES = sorted((ROOT / 'config' / 'fleets').glob('*.yaml'))


def _paths(doc, prefix=()):
    """Every key path of a YAML document (mappings and lists), the root included."""
    out = [prefix]
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in items:
        out += _paths(value, prefix + (key,))
    return out


@st.composite
def hostile_yaml_file(draw, files):
    """A shipped YAML file's document with up to four entries replaced by any value, dropped, or
    given a sibling, written by yaml.safe_dump, and maybe a tagged line after it; or any text."""
    doc = copy.deepcopy(_yaml_doc(draw(st.sampled_from(files))))
    for _ in range(draw(st.integers(0, 4))):
        path = draw(st.sampled_from(_paths(doc)))
        if not path:
            doc = draw(json_values)
            continue
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        how = draw(st.sampled_from(['replace', 'drop', 'add']))
        if how == 'replace' or (how == 'drop' and isinstance(parent, list)):
            parent[path[-1]] = draw(json_values)
        elif how == 'drop':
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.text(max_size=8))] = draw(json_values)
        else:
            parent.append(draw(json_values))
    text = yaml.safe_dump(doc) + draw(st.just('') | tagged_yaml.map(lambda t: f'\nextra: {t}\n'))
    return draw(st.just(text) | st.text(max_size=100) | nested_yaml)


@budget(100)
@given(hostile_yaml_file(SCENARIO_FILES))
@example('name: x\ndimensions: !!int\n')  # pyyaml: once an IndexError
def test_scenario_files_load_or_are_refused(text):
    from knode_swarm_ros.core.scenarios import Scenario, ScenarioError, get_scenario

    with _tmpdir() as tmp:
        path = Path(tmp) / 'custom.yaml'
        path.write_text(text)
        try:
            spec = get_scenario(str(path))
        except ScenarioError:
            return
        assert isinstance(spec, Scenario) and spec.state_dim > 0 and spec.command_dim > 0


@budget(100)
@given(hostile_yaml_file(FLEET_FILES), st.booleans())
@example('robots: !!bool maybe\n', False)  # pyyaml: once a KeyError
@example('robots: fleet.yaml\n', False)  # a robots file that is the fleet file itself
def test_fleet_files_load_or_are_refused(text, beside):
    """``beside``: the file is also there as ``crazyflies.yaml``, which ``robots:`` may name."""
    from knode_swarm_ros.logic.contract.fleet import Fleet, load_fleet

    with _tmpdir() as tmp:
        path = Path(tmp) / 'fleet.yaml'
        path.write_text(text)
        if beside:
            (Path(tmp) / 'crazyflies.yaml').write_text(text)
        try:
            fleet = load_fleet(str(path))
        except ConfigError:
            return
        assert isinstance(fleet, Fleet) and len(fleet.robots) >= 1


# --- node parameter files ---------------------------------------------------------------------------

AGENT_PARAMS = [
    'robots',
    'robot_ids',
    'scenario',
    'policy',
    'policy_runtime',
    'mode',
    'control_rate',
    'state_timeout',
    'future_tolerance',
    'command_limit',
    'k',
    'stat_timeout',
]


@pytest.fixture(scope='module')
def ros_context():
    """One context for every example, with a node that keeps its DDS participant alive (a fresh
    context per example makes a fresh participant: most of an example's time). Each example's
    ``--params-file`` is the ROS arguments of its own node, which rcl parses with the same parser
    as a context's (``rcl_parse_arguments``) and merges into the node's overrides alike."""
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    anchor = rclpy.create_node('fuzz_anchor', context=ctx, start_parameter_services=False)
    yield rclpy, ctx
    anchor.destroy_node()
    rclpy.shutdown(context=ctx)


@budget(30)
@given(
    st.one_of(
        st.dictionaries(st.sampled_from(AGENT_PARAMS), json_values, max_size=4).map(
            lambda p: yaml.safe_dump({'/**': {'ros__parameters': p}})
        ),
        st.text(max_size=100),
        nested,
        st.tuples(st.sampled_from(AGENT_PARAMS), tagged_yaml).map(
            lambda p: f'/**:\n  ros__parameters:\n    {p[0]}: {p[1]}\n'
        ),
    ),
    st.booleans(),
)
def test_agent_params_files_are_read_or_refused(ros_context, text, p_first):
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    from knode_swarm_ros.nodes.agent.params import declare_agent_parameters
    from knode_swarm_ros.nodes.common.params import check_overrides

    rclpy, ctx = ros_context
    with _tmpdir() as tmp:
        path = Path(tmp) / 'params.yaml'
        path.write_text(text)
        # -p before the file: check_overrides reads the file itself (a -p that the file overrides)
        argv = ['--ros-args'] + (['-p', 'robots:=3'] if p_first else []) + ['--params-file', str(path)]
        try:
            node = rclpy.create_node('agent_0', context=ctx, cli_args=argv, start_parameter_services=False)
        except _rclpy.RCLError:
            return  # run_node refuses it: ConfigError 'cannot parse the ROS arguments' (exit 2)
        try:
            declare_agent_parameters(node)
            check_overrides(node, argv)
        except ConfigError:
            pass
        finally:
            node.destroy_node()


def test_every_error_a_reader_raises_is_a_knode_error():
    """The documented classes the properties accept are the project's (exit 2 from a command)."""
    from knode_swarm_ros.bag.messages import BagError

    for cls in (cdr.CdrError, TrajectoryError, PolicyError, BagError, ConfigError):
        assert issubclass(cls, KnodeError) and cls.exit_status == 2
