"""Every front end's parameters, built one way: parameter files, then ``NAME=VALUE``, then options.

The names are those of ``pearl_node``'s ROS parameters: the fields of
:class:`~pearl_ros.core.config.PearlConfig` and :class:`~pearl_ros.online.config.OnlineConfig`
(:func:`pearl_ros.online.config.known_names`), and the node's own, :class:`NodeConfig`. The node
declares them (:mod:`pearl_ros.ros.params`); ``pearl_replay`` and ``pearl_bench`` read the same
names from the same files and ``--set`` strings, with the same checks:

- an unknown name is refused, suggesting the closest known one;
- a ROS parameter file whose entries are all for other nodes is refused, saying so;
- an integer is accepted for a float parameter (YAML's ``label_cost: 300``, ``-p ...:=300``).

ROS-free: nothing here imports rclpy.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pearl_ros.bagio import decode
from pearl_ros.core.config import ParameterSpec, check_fields, parameter_specs, spec
from pearl_ros.core.errors import InputError, one_line
from pearl_ros.online import config as online_config

NODE_NAME = 'pearl_node'
NODE_FQN = '/' + NODE_NAME  # the node's fully qualified name when nothing remaps it
MSG_TYPES = ('PointCloud', 'PointCloud2')
QOS_CHOICES = ('sensor_data', 'reliable')
QUEUE_POLICIES = ('newest', 'all')
POSE_CHOICES = ('odometry', 'pose_stamped', 'pose_with_covariance_stamped')
_INT64 = 2**63 - 1

# Parameters that rclpy declares on every node itself: a node's parameter file may set them.
ROS_PARAMETERS = ('use_sim_time', 'start_type_description_service')
_ROS_PREFIXES = ('qos_overrides.',)


@dataclass(frozen=True)
class NodeConfig:
    """``pearl_node``'s own parameters: its input, QoS, caps and annotated images.

    ``pearl_replay`` applies :data:`PIPELINE_NAMES` (they change what is computed); the others
    are about live transport and mean nothing in a replay. :mod:`pearl_ros.ros.params` makes
    those that fix the subscription and the timers read-only after start-up.
    """

    msg_type: str = spec('PointCloud', 'input message type on `features`: '
                         'sensor_msgs/msg/PointCloud (VINS) or PointCloud2 (fields id and u, v '
                         'or x, y)', choices=MSG_TYPES)
    layout: str = spec('auto', 'PointCloud channel layout: vins_mono (channels by name), '
                       'vins_fusion (by index: id, camera, u, v, ...), auto (vins_mono if a '
                       'channel is named id_of_point)', choices=decode.LAYOUTS)
    camera_id: int = spec(0, 'camera whose features are segmented (vins_fusion layout); the '
                          "other cameras' features pass to static_features untouched",
                          low=0, high=1_000_000)
    qos: str = spec('sensor_data', 'input QoS: sensor_data (best effort, keep last qos_depth) '
                    'or reliable (keep last qos_depth; VINS publishes reliable)',
                    choices=QOS_CHOICES)
    qos_depth: int = spec(5, 'messages, input queue depth', low=1, high=100_000)
    queue_policy: str = spec('newest', 'what a node slower than its input answers: newest (the '
                             'newest message; one a newer message replaced before the node got '
                             'to it is dropped) or all (every message in arrival order, at most '
                             'qos_depth waiting; beyond, the oldest is dropped); drops are '
                             'counted in /diagnostics', choices=QUEUE_POLICIES)
    max_features: int = spec(2000, 'features per message fed to the segmenter; a larger message '
                             'is subsampled by a hash of the ids (the same ids kept every '
                             'frame), the rest labelled -1', low=1, high=10_000_000)
    background_motion: int = spec(-1, 'motion number published on static_features; -1 = the '
                                  'static world where pose_topic gives the camera poses, else '
                                  'the motion with the most features (ties: the lowest number)',
                                  low=-1, high=_INT64)
    diagnostics_period: float = spec(1.0, 's, period of /diagnostics and of the check for '
                                     'publishers of another type on `features`',
                                     low=0.01, high=3600.0)
    image_topic: str = spec('', 'sensor_msgs/msg/Image topic to draw the labels on: when set, '
                            'each image is matched to the feature message of the same stamp '
                            'and published on image_labels (bgr8, the features as dots in '
                            "their motion's colour); empty = off")
    pose_topic: str = spec('', "the camera's pose in a fixed world frame, per frame (a robot's "
                           'odometry, such as VINS\' camera_pose): the pose of its optical frame '
                           '(z forward, x right, y down), of type pose_type; with the '
                           'intrinsics (camera_info_topic, or camera_fx, camera_fy, camera_cx, '
                           'camera_cy), the static world becomes a motion '
                           'of known parameters; empty = off')
    pose_type: str = spec('odometry', 'message type on pose_topic: odometry '
                          '(nav_msgs/msg/Odometry), pose_stamped '
                          '(geometry_msgs/msg/PoseStamped) or pose_with_covariance_stamped '
                          '(geometry_msgs/msg/PoseWithCovarianceStamped; the covariance is not '
                          'used)', choices=POSE_CHOICES)
    pose_tolerance_ms: float = spec(10.0, 'ms, the most a pose\'s stamp may differ from its '
                                    "feature frame's", low=0.0, high=1e6)
    camera_info_topic: str = spec('', 'sensor_msgs/msg/CameraInfo topic of the camera whose '
                                  'features are segmented, the latest valid one in use: its '
                                  'lens distortion (d) is undone on the features before they '
                                  'are segmented, and with pose_topic its k (for the binning '
                                  'and roi it gives) replaces camera_fx, camera_fy, camera_cx, '
                                  'camera_cy (frames before the first get no camera); empty = '
                                  'off (pixels as they come, the parameters\' intrinsics)')
    camera_fx: float = spec(0.0, 'px, focal length along x of the camera whose features are '
                            'segmented (needed with pose_topic, unless camera_info_topic)',
                            low=0.0, high=1e9)
    camera_fy: float = spec(0.0, 'px, focal length along y (needed with pose_topic, unless '
                            'camera_info_topic)', low=0.0, high=1e9)
    camera_cx: float = spec(0.0, 'px, principal point x', low=-1e9, high=1e9)
    camera_cy: float = spec(0.0, 'px, principal point y', low=-1e9, high=1e9)
    mount_x: float = spec(0.0, "m, the camera's optical frame in the frame whose pose comes on "
                          'pose_topic (its child frame, e.g. base_link): x of its origin; 0 '
                          'with mount_y, mount_z, mount_qx, mount_qy, mount_qz and mount_qw '
                          '1: the poses are the camera\'s own (VINS camera_pose)',
                          low=-1e6, high=1e6)
    mount_y: float = spec(0.0, 'm, y of the optical frame\'s origin (see mount_x)',
                          low=-1e6, high=1e6)
    mount_z: float = spec(0.0, 'm, z of the optical frame\'s origin (see mount_x)',
                          low=-1e6, high=1e6)
    mount_qx: float = spec(0.0, "x of the optical frame's orientation quaternion (see mount_x)",
                           low=-1.0, high=1.0)
    mount_qy: float = spec(0.0, "y of the optical frame's orientation quaternion", low=-1.0,
                           high=1.0)
    mount_qz: float = spec(0.0, "z of the optical frame's orientation quaternion", low=-1.0,
                           high=1.0)
    mount_qw: float = spec(1.0, "w of the optical frame's orientation quaternion", low=-1.0,
                           high=1.0)

    def __post_init__(self) -> None:
        check_fields(self)
        if not any((self.mount_qx, self.mount_qy, self.mount_qz, self.mount_qw)):
            raise InputError('mount_qx, mount_qy, mount_qz, mount_qw: the quaternion of the '
                             "camera's mounting must not be zero (identity: mount_qw 1)")
        if (self.pose_topic and not self.camera_info_topic
                and not (self.camera_fx > 0 and self.camera_fy > 0)):
            raise InputError('pose_topic needs the camera intrinsics: camera_info_topic, or '
                             'camera_fx and camera_fy > 0 (and camera_cx, camera_cy), in the '
                             'pixels of the features')


NODE_SPECS: tuple[ParameterSpec, ...] = parameter_specs(NodeConfig)
NODE_NAMES = tuple(item.name for item in NODE_SPECS)
# The node parameters the per-message pipeline reads (pearl_replay applies them too).
PIPELINE_NAMES = ('layout', 'camera_id', 'max_features', 'background_motion', 'pose_topic',
                  'pose_type', 'pose_tolerance_ms', 'camera_info_topic', 'camera_fx', 'camera_fy',
                  'camera_cx', 'camera_cy', 'mount_x', 'mount_y', 'mount_z', 'mount_qx',
                  'mount_qy', 'mount_qz', 'mount_qw')


def _default_configs() -> tuple[Any, ...]:
    return online_config.build_configs({})


@dataclass(frozen=True)
class Settings:
    """Everything the per-message pipeline and the node are configured with.

    Attributes
    ----------
    configs : tuple
        The segmenter's configuration objects as
        :func:`~pearl_ros.online.config.build_configs` returns them, in
        ``OnlineSegmenter(*configs)`` order: ``(PearlConfig, OnlineConfig)``.
    node : NodeConfig
    """

    configs: tuple[Any, ...] = field(default_factory=_default_configs)
    node: NodeConfig = field(default_factory=NodeConfig)

    @property
    def config(self) -> Any:
        """The :class:`~pearl_ros.core.config.PearlConfig`."""
        return self.configs[0]

    @property
    def online(self) -> Any:
        """The :class:`~pearl_ros.online.config.OnlineConfig`."""
        return self.configs[1]

    def values(self, names: Collection[str] | None = None) -> dict[str, Any]:
        """Parameter name -> value, of every parameter or of ``names`` only.

        The parameters are those :func:`~pearl_ros.core.config.parameter_specs` lists (the
        node's), not nested settings such as ``PearlConfig.solver``.
        """
        out = {item.name: getattr(obj, item.name) for obj in (*self.configs, self.node)
               for item in parameter_specs(type(obj))}
        return out if names is None else {k: v for k, v in out.items() if k in names}


def known_names() -> tuple[str, ...]:
    """Every parameter name a front end takes: the configuration objects', then the node's."""
    return online_config.known_names() + NODE_NAMES


def is_ros_parameter(name: str) -> bool:
    """A parameter rclpy declares on every node (``use_sim_time``, ``qos_overrides.*``...)."""
    return name in ROS_PARAMETERS or name.startswith(_ROS_PREFIXES)


def check_names(names: Iterable[str], refused: Collection[str] = (), where: str = '') -> None:
    """Raise InputError for the first unknown name (suggesting the closest known one), or the
    first of ``refused`` (names a command has no use for).

    ``where`` prefixes the message (``'parameter file p.yaml: '``).
    """
    known = known_names()
    for name in names:
        if name in refused:
            raise InputError(f'{where}parameter {name!r} does not apply to this command')
        if name not in known:
            err = online_config.unknown_parameter(name, [k for k in known if k not in refused])
            raise InputError(f'{where}{err}')


def parse_assignments(items: Iterable[str], refused: Collection[str] = ()) -> dict[str, Any]:
    """``NAME=VALUE`` strings to typed values; names checked as :func:`check_names` does.

    Raises
    ------
    InputError
        A malformed item, an unknown name (with the closest one), a value of the wrong type.
    """
    specs = {item.name: item for item in NODE_SPECS}
    out: dict[str, Any] = {}
    for item in items:
        name, text = online_config.split_assignment(item)
        check_names([name], refused)
        if name not in specs:
            out.update(online_config.parse_assignments([f'{name}={text}']))
            continue
        kind = specs[name].type
        try:
            out[name] = kind(text.strip()) if kind is not str else text.strip()
        except ValueError as err:
            raise InputError(f'invalid value for {name}: {text!r} is not '
                             f'{kind.__name__}') from err
    return out


def build(values: Mapping[str, Any], base: Settings | None = None,
          refused: Collection[str] = ()) -> Settings:
    """The settings from ``values`` (parameter name -> value) over ``base`` (default: defaults).

    Raises
    ------
    InputError
        An unknown name (with the closest known one), a value of the wrong type, out of range or
        not among the choices (naming it).
    """
    check_names(values, refused)
    base = base or Settings()
    configs = online_config.build_configs(
        {k: v for k, v in values.items() if k not in NODE_NAMES}, base.configs)
    mine = {k: v for k, v in values.items() if k in NODE_NAMES}
    for item in NODE_SPECS:  # an int given for a float parameter is that float
        if item.type is float and type(mine.get(item.name)) is int:
            mine[item.name] = float(mine[item.name])
    return Settings(tuple(configs), dataclasses.replace(base.node, **mine))


def from_sources(files: Sequence[str | Path] = (), assignments: Sequence[str] = (),
                 options: Mapping[str, Any] | None = None,
                 refused: Collection[str] = ()) -> Settings:
    """A command line's settings: parameter files in order, then ``NAME=VALUE``, then options.

    ``options`` are values from a front end's own flags (``--layout``); a None value is a flag
    not given. Later sources win.
    """
    values: dict[str, Any] = {}
    for path in files:
        loaded = load_file(path, flat=True)
        check_names(loaded, refused, where=f'parameter file {path}: ')
        values.update(loaded)
    values.update(parse_assignments(assignments, refused))
    values.update({k: v for k, v in (options or {}).items() if v is not None})
    return build(values, refused=refused)


def load_file(path: str | Path, node: str | None = NODE_FQN, *, flat: bool = False
              ) -> dict[str, Any]:
    """Parameter name -> value for the node ``node`` from a YAML parameter file.

    A ROS 2 parameter file maps node names to ``ros__parameters``; names may be nested
    (``ns: {pearl_node: ...}``) and hold the wildcards ``*`` (one name) and ``**`` (any, as in
    ``/**``), as rcl reads them. The entries that apply to ``node`` are merged in file order;
    nested parameter namespaces come out as dotted names. The parameters rclpy declares itself
    (:data:`ROS_PARAMETERS`) are left out.

    Parameters
    ----------
    path : str or Path
    node : str or None
        Fully qualified node name (``/pearl_node``, ``/robot/pearl_node``); None: check the file
        only, return every entry's parameters merged.
    flat : bool
        Also accept a flat ``name: value`` mapping (pearl_replay); rcl refuses one.

    Raises
    ------
    InputError
        Unreadable file, not YAML, not a mapping, not a ROS parameter file (unless ``flat``),
        or no entry for ``node`` (the message lists the entries).
    """
    data = _read_yaml(Path(path))
    entries = _ros_entries(data, path)
    if not entries:
        if not flat and data:
            raise InputError(f'parameter file {path} is not a ROS parameter file: expected '
                             f'{NODE_NAME}: (or /**:) with ros__parameters: under it')
        return _without_ros(_flatten(data))
    chosen = [params for key, params in entries if node is None or _applies(key, node)]
    if not chosen and node is not None:
        keys = ', '.join(key for key, _ in entries)
        raise InputError(f'parameter file {path} has no parameters for {node}: its entries are '
                         f"for {keys} (name the node as '{node.rsplit('/', 1)[-1]}:' or "
                         "'/**:')")
    out: dict[str, Any] = {}
    for params in chosen:
        out.update(_flatten(params))
    return _without_ros(out)


def _read_yaml(path: Path) -> Any:
    from ruamel.yaml import YAML, YAMLError  # a dependency of rosbags

    try:
        text = path.read_text()
    except OSError as err:
        raise InputError(f'cannot read parameter file {path}: {err.strerror or err}') from err
    try:
        data = YAML(typ='safe', pure=True).load(text)
    except (YAMLError, ValueError) as err:
        raise InputError(f'parameter file {path} is not valid YAML: {one_line(err, 200)}') from err
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise InputError(f'parameter file {path} must hold a mapping, got {type(data).__name__}')
    return data


def _ros_entries(data: Mapping[str, Any], path: str | Path, prefix: str = ''
                 ) -> list[tuple[str, Mapping[str, Any]]]:
    """``(node key, parameters)`` of every ``ros__parameters`` mapping, nested keys joined."""
    out = []
    for name, value in data.items():
        if not isinstance(value, Mapping):
            continue
        key = f'{prefix}/{str(name).strip("/")}'
        if 'ros__parameters' in value:
            params = value['ros__parameters'] or {}
            if not isinstance(params, Mapping):
                raise InputError(f'parameter file {path}: ros__parameters of {key} must be a '
                                 'mapping')
            out.append((key, params))
        else:
            out.extend(_ros_entries(value, path, key))
    return out


def _applies(key: str, node: str) -> bool:
    """Does the entry ``key`` (``/ns/name``, wildcards ``*`` and ``**``) name ``node``?"""
    parts = []
    for token in key.strip('/').split('/'):
        parts.append({'**': '(?:/[^/]+)*', '*': '/[^/]+'}.get(token, '/' + re.escape(token)))
    return re.fullmatch(''.join(parts), node) is not None


def _flatten(params: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """Nested ROS parameter namespaces as dotted names."""
    out: dict[str, Any] = {}
    for name, value in params.items():
        key = f'{prefix}{name}'
        if isinstance(value, Mapping):
            out.update(_flatten(value, key + '.'))
        else:
            out[key] = value
    return out


def _without_ros(values: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in values.items() if not is_ros_parameter(k)}
