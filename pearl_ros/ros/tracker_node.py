"""``pearl_tracker``: a KLT feature tracker node that keeps the features of moving objects.

Topics (names relative to the node's namespace unless absolute)

``image`` (in)
    ``sensor_msgs/msg/Image``, encodings mono8, mono16, bgr8, rgb8, bgra8, rgba8
    (:mod:`pearl_ros.tracking.image`). Another encoding is counted in the diagnostics and answered
    by a throttled one-line warning; the node goes on.
``camera_info`` (in, optional)
    ``sensor_msgs/msg/CameraInfo`` (plumb_bob, rational_polynomial, equidistant). The latest
    valid one is the camera model; until one arrives the points are pixels.
``features`` (out)
    ``sensor_msgs/msg/PointCloud`` in VINS-Mono's layout, with the image's header: ``points[i]``
    = undistorted normalised ``(x, y, 1)`` when intrinsics are known, else pixels ``(u, v, 1)``;
    channels ``id_of_point`` (modulo 2^24: :func:`features_message`), ``u_of_point``,
    ``v_of_point`` (pixels), ``velocity_x_of_point``,
    ``velocity_y_of_point`` (of the points: normalised or pixel units, per second when both
    frames have stamps). ``pearl_node`` (msg_type PointCloud, layout auto) and a VINS estimator
    both read it.
``/diagnostics`` (out)
    ``diagnostic_msgs/msg/DiagnosticArray`` every ``diagnostics_period`` s.

Unlike VINS-Mono's ``feature_tracker`` every image that can be read is published, the first one
included (its features all new, velocities 0): a segmenter downstream then labels every frame.
A stamp that goes back in time (a bag replayed in a loop) ends every track; ids still count on.

The tracker (:class:`~pearl_ros.tracking.tracker.FeatureTracker`) is configured by the fields of
:class:`~pearl_ros.tracking.tracker.TrackerConfig`, declared as read-only ROS parameters with
their descriptions and ranges, plus the node's own (:class:`TrackerNodeConfig`).

SIGINT or SIGTERM stops the node between two callbacks, with exit status 0.
"""

from __future__ import annotations

import sys
import textwrap
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image, PointCloud
from std_msgs.msg import Header

from pearl_ros.bagio import cdr, decode
from pearl_ros.core.config import ParameterSpec, check_fields, check_value, parameter_specs, spec
from pearl_ros.core.errors import InputError, one_line
from pearl_ros.online.config import unknown_parameter
from pearl_ros.pipeline import settings as pipeline_settings
from pearl_ros.ros import params, runner
from pearl_ros.ros.node import input_qos
from pearl_ros.tracking import image as image_io
from pearl_ros.tracking.tracker import CameraModel, FeatureTracker, TrackerConfig, Tracks

NODE_NAME = 'pearl_tracker'
OUTPUT_DEPTH = 10  # messages, keep-last depth of the (reliable) output
CHANNELS = ('id_of_point', 'u_of_point', 'v_of_point', 'velocity_x_of_point',
            'velocity_y_of_point')
ID_MODULUS = 2**24  # published ids wrap here (float32 channels, features_message)


@dataclass(frozen=True)
class TrackerNodeConfig:
    """``pearl_tracker``'s own parameters: input QoS, image conversion, diagnostics."""

    qos: str = spec('sensor_data', 'input QoS of image and camera_info: sensor_data (best '
                    'effort, keep last qos_depth; takes reliable publishers too) or reliable',
                    choices=pipeline_settings.QOS_CHOICES)
    qos_depth: int = spec(1, 'images, input queue depth (1: always the newest image)',
                          low=1, high=100_000)
    mono16_shift: int = spec(8, 'bits a mono16 image is shifted right to make it 8-bit (8: the '
                             'full 16-bit range, as cv_bridge; 4: a 12-bit camera)',
                             low=0, high=16)
    diagnostics_period: float = spec(1.0, 's, period of /diagnostics', low=0.01, high=3600.0)

    def __post_init__(self) -> None:
        check_fields(self)


TRACKER_SPECS: tuple[ParameterSpec, ...] = parameter_specs(TrackerConfig)
NODE_SPECS: tuple[ParameterSpec, ...] = parameter_specs(TrackerNodeConfig)
ALL_SPECS: tuple[ParameterSpec, ...] = TRACKER_SPECS + NODE_SPECS
NAMES: tuple[str, ...] = tuple(item.name for item in ALL_SPECS)


def build_configs(values: Mapping[str, Any]) -> tuple[TrackerConfig, TrackerNodeConfig]:
    """The two configurations from parameter name -> value (others at their defaults).

    Raises
    ------
    InputError
        An unknown name (with the closest known one), a value of the wrong type or out of range.
    """
    unknown = [name for name in values if name not in NAMES]
    if unknown:
        raise unknown_parameter(unknown[0], NAMES)
    checked = {}
    for item in ALL_SPECS:
        value = values.get(item.name, item.default)
        if item.type is float and type(value) is int:
            value = float(value)
        check_value(item, value)
        checked[item.name] = value
    tracker = TrackerConfig(**{item.name: checked[item.name] for item in TRACKER_SPECS})
    node = TrackerNodeConfig(**{item.name: checked[item.name] for item in NODE_SPECS})
    return tracker, node


def features_message(header: Header, tracks: Tracks) -> cdr.PointCloud:
    """The VINS-Mono ``PointCloud`` of one frame's tracks (module docstring for the layout), as a
    :mod:`~pearl_ros.bagio.cdr` message: arrays, published as its bytes
    (:func:`~pearl_ros.bagio.cdr.serialize`), with no Python object per feature.

    Ids are published modulo :data:`ID_MODULUS`: a float32 channel holds integers exactly only
    up to 2^24, which a tracker detecting ~1000 corners a second passes in about five hours. An
    id comes back only after 2^24 newer ones, long after its track ended.
    """
    if tracks.xy is not None and tracks.xy_velocity is not None:
        points, velocity = tracks.xy, tracks.xy_velocity
    else:
        points, velocity = tracks.uv, tracks.velocity
    columns = (tracks.ids % ID_MODULUS, tracks.uv[:, 0], tracks.uv[:, 1], velocity[:, 0],
               velocity[:, 1])
    xyz = np.column_stack((points, np.ones(len(points)))).astype(np.float32)
    return cdr.PointCloud(
        header=header,
        points=xyz.reshape(-1, 3),
        channels=[cdr.ChannelFloat32(name, np.asarray(values, dtype=np.float32))
                  for name, values in zip(CHANNELS, columns, strict=True)],
    )


@dataclass
class Stats:
    """Counters since start-up, and what the current diagnostics period saw."""

    received: int = 0
    published: int = 0
    bad_encoding: int = 0  # an encoding tracking.image does not read
    malformed: int = 0  # a supported encoding, but step or data do not fit
    bad_camera_info: int = 0  # CameraInfo refused (uncalibrated, unknown model)
    resets: int = 0  # stamp went back in time: tracks ended
    errors: int = 0  # unexpected exceptions (a bug), the node carried on
    features: int = 0  # last frame
    new_features: int = 0  # last frame
    period_start: float = field(default_factory=time.monotonic)
    period_received: int = 0
    period_problems: int = 0
    period_track_s: list[float] = field(default_factory=list)


class TrackerNode(Node):
    """The tracker node (module docstring). Keyword arguments go to ``rclpy.node.Node``.

    Parameters
    ----------
    node_name : str
    params_files : sequence of str
        The ``--params-file`` files of the process' ROS arguments (``main`` passes them): each
        must have an entry for this node, with known names only.

    Raises
    ------
    InputError
        A parameter override of an unknown name, of the wrong type or out of range; a parameter
        file without an entry for this node.
    """

    def __init__(self, node_name: str = NODE_NAME, *, params_files: Sequence[str] = (),
                 **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        try:
            files = [*params_files, *params.params_files(kwargs.get('cli_args') or ())]
            _check_params_files(files, self.get_fully_qualified_name())
            # rclpy keeps the overrides it parsed (files, -p, parameter_overrides) here and
            # offers no public accessor; _declare checks and applies them.
            self.tracker_config, self.config = _declare(self, self._parameter_overrides)
        except BaseException:
            self.destroy_node()
            raise
        self._tracker = FeatureTracker(self.tracker_config)
        self._camera_key: tuple[Any, ...] | None = None
        self._last_stamp: int | None = None
        self.stats = Stats()
        self._throttle = runner.Throttle(self)
        qos = input_qos(self.config.qos, self.config.qos_depth)
        self._image_sub = self.create_subscription(Image, 'image', self._on_image, qos)
        self._info_sub = self.create_subscription(CameraInfo, 'camera_info',
                                                  self._on_camera_info, qos)
        output_qos = QoSProfile(depth=OUTPUT_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        self._features_pub = self.create_publisher(PointCloud, 'features', output_qos)
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._timer = self.create_timer(self.config.diagnostics_period, self._on_timer)
        self.get_logger().info(
            f'tracking {self._image_sub.topic_name} into {self._features_pub.topic_name} '
            f'({self.tracker_config.max_features} features, qos {self.config.qos})')

    @property
    def camera(self) -> CameraModel | None:
        """The camera model in use (from the latest valid ``camera_info``), or None."""
        return self._tracker.camera

    def _on_camera_info(self, msg: CameraInfo) -> None:
        """Use the intrinsics and distortion of ``msg`` from the next image on.

        A refused one (an uncalibrated driver's all-zero K) is counted and warned about once,
        not at every message; the previous model stays.
        """
        key = (tuple(msg.k), tuple(msg.d), str(msg.distortion_model))
        if key == self._camera_key:
            return
        self._camera_key = key
        try:
            camera = CameraModel.from_camera_info(msg)
        except InputError as err:
            self.stats.bad_camera_info += 1
            self.stats.period_problems += 1
            self._throttle.warn('camera_info', f'camera_info refused, points stay as before: '
                                f'{one_line(err)}')
            return
        self._tracker.camera = camera
        self.get_logger().info(f'camera model from {self._info_sub.topic_name}: '
                               f'{camera.model}, points are normalised coordinates')

    def _on_image(self, msg: Image) -> None:
        """Track into one image and publish its features; a bad image is counted and warned."""
        stats = self.stats
        stats.received += 1
        stats.period_received += 1
        start = time.perf_counter()  # the frame's whole work: conversion, tracking, message
        gray = self._grey(msg)
        if gray is None:
            stats.period_problems += 1
            return
        stamp = decode.stamp_ns(msg.header)
        if self._last_stamp is not None and stamp < self._last_stamp:
            stats.resets += 1
            self._tracker.reset()
            self.get_logger().warning(f'stamp {stamp} ns went back in time: tracks ended '
                                      '(bag replayed in a loop?)')
        self._last_stamp = stamp
        try:
            tracks = self._tracker.track(gray, stamp)
            out = features_message(msg.header, tracks)
        except Exception as err:  # a bug must not take the node down with it
            stats.errors += 1
            stats.period_problems += 1
            self._throttle.warn('error', f'internal error, image dropped: '
                                f'{type(err).__name__}: {one_line(err)}')
            return
        stats.period_track_s.append(time.perf_counter() - start)
        try:
            self._features_pub.publish(cdr.serialize(out))
        except Exception:
            if self.context.ok():
                raise
            return  # the context was shut down under this callback: nobody is listening
        stats.published += 1
        stats.features = len(tracks)
        stats.new_features = int(np.count_nonzero(tracks.age == 1))

    def _grey(self, msg: Image) -> np.ndarray | None:
        """The 8-bit grey image of ``msg``, or None (counted and warned) if it cannot be read."""
        encoding = str(msg.encoding)
        if encoding not in image_io.ENCODINGS:
            self.stats.bad_encoding += 1
            self._throttle.warn('encoding', f'image encoding {encoding!r} not supported '
                                f'(supported: {", ".join(image_io.ENCODINGS)}): image dropped')
            return None
        try:
            pixels = image_io.image_to_array(msg)
            return image_io.to_mono8(pixels, encoding, self.config.mono16_shift)
        except InputError as err:
            self.stats.malformed += 1
            self._throttle.warn('malformed', f'malformed image dropped: {one_line(err)}')
            return None

    def set_parameters_atomically(self, parameter_list: list[Parameter[Any]]
                                  ) -> SetParametersResult:
        """As rclpy's, but an undeclared name is refused naming it and the closest known one."""
        unknown = [p.name for p in parameter_list if not self.has_parameter(p.name)]
        if unknown:
            reason = str(unknown_parameter(unknown[0], NAMES))
            return SetParametersResult(successful=False, reason=reason)
        return super().set_parameters_atomically(parameter_list)

    def _on_timer(self) -> None:
        try:
            self._diagnostics_pub.publish(self.diagnostics())
        except Exception:
            if self.context.ok():
                raise

    def diagnostics(self) -> DiagnosticArray:
        """The status of the last period, and starts a new period."""
        stats = self.stats
        now = time.monotonic()
        elapsed = max(now - stats.period_start, 1e-9)
        track_ms = np.asarray(stats.period_track_s) * 1e3
        problems = []
        if stats.period_problems:
            problems.append(f'{stats.period_problems} image(s) or camera_info refused')
        if not stats.period_received:
            problems.append('no input')
        camera = self.camera
        values = {
            'input rate (Hz)': f'{stats.period_received / elapsed:.2f}',
            'tracker mean (ms per frame)': f'{track_ms.mean():.2f}' if track_ms.size else '',
            'tracker max (ms per frame)': f'{track_ms.max():.2f}' if track_ms.size else '',
            'features': stats.features,
            'new features': stats.new_features,
            'images received': stats.received,
            'frames published': stats.published,
            'bad encodings': stats.bad_encoding,
            'malformed images': stats.malformed,
            'camera_info refused': stats.bad_camera_info,
            'camera model': camera.model if camera is not None else 'none (points in pixels)',
            'track resets (stamp went back)': stats.resets,
            'internal errors': stats.errors,
        }
        stats.period_start, stats.period_received, stats.period_problems = now, 0, 0
        stats.period_track_s = []
        return runner.diagnostics(self, 'feature tracking', 'tracking', problems, values)


def _declare(node: Node, overrides: Mapping[str, Parameter[Any]]
             ) -> tuple[TrackerConfig, TrackerNodeConfig]:
    """Declare every parameter on ``node`` (read-only, with description and range), overrides
    checked and applied; returns the configurations."""
    unknown = [name for name in overrides
               if name not in NAMES and not pipeline_settings.is_ros_parameter(name)]
    if unknown:
        raise unknown_parameter(unknown[0], NAMES)
    tracker, config = build_configs({name: overrides[name].value for name in NAMES
                                     if name in overrides})
    for item in ALL_SPECS:
        owner: Any = tracker if item.name in TrackerConfig.__dataclass_fields__ else config
        desc = params.descriptor(item)
        # The tracker's state (templates, window size) is built from these at start-up.
        desc.read_only = True
        node.declare_parameter(item.name, getattr(owner, item.name), desc,
                               ignore_override=True)
    return tracker, config


def _check_params_files(paths: Sequence[str], node: str) -> None:
    """Raise InputError unless each ROS parameter file has an entry for ``node``, with known
    names only (they would be ignored without a word)."""
    for path in paths:
        values = pipeline_settings.load_file(path, node)
        unknown = [name for name in values if name not in NAMES]
        if unknown:
            raise InputError(f'parameter file {path}: {unknown_parameter(unknown[0], NAMES)}')


def help_text() -> str:
    """Every parameter with its default, range and description, for ``--help``."""
    lines = []
    for item in ALL_SPECS:
        if item.choices is not None:
            allowed = 'one of ' + ' | '.join(item.choices)
        else:
            allowed = f'{item.low:g} .. {item.high:g}' if item.low is not None else ''
        lines.append(f'  {item.name}: {item.default}' + (f'  ({allowed})' if allowed else ''))
        lines.extend(textwrap.wrap(item.doc, 95, initial_indent=' ' * 6,
                                   subsequent_indent=' ' * 6))
    return '\n'.join(lines)


USAGE = """usage: pearl_tracker [-h] [--ros-args [-r image:=TOPIC] [-r camera_info:=TOPIC]
                     [--params-file FILE] [-p NAME:=VALUE] ...]

KLT feature tracker for pearl_node and VINS: Shi-Tomasi corners tracked by pyramidal Lucas-Kanade
with a forward-backward check, persistent ids, and no epipolar (RANSAC) rejection, so that moving
objects keep their features. Every readable image is published, the first one included.

topics (relative to the node's namespace; remap `image` and `camera_info` to the camera's):
  image (in)             sensor_msgs/msg/Image: mono8, mono16, bgr8, rgb8, bgra8, rgba8
  camera_info (in)       sensor_msgs/msg/CameraInfo, optional (plumb_bob, rational_polynomial,
                         equidistant): points become undistorted normalised coordinates
  features (out)         sensor_msgs/msg/PointCloud, VINS-Mono layout: points (x, y, 1)
                         normalised (pixels without camera_info); channels id_of_point,
                         u_of_point, v_of_point, velocity_x_of_point, velocity_y_of_point
  /diagnostics (out)     diagnostic_msgs/msg/DiagnosticArray every diagnostics_period s

parameters (NAME: default (range), description; read-only, set at start-up with -p NAME:=VALUE
or a parameter file whose top key is pearl_tracker or /**; an unknown name is refused):
{parameters}

example (feeding pearl_node, whose input is `features` in the same namespace):
  pearl_tracker --ros-args -r image:=/camera/image_raw -r camera_info:=/camera/camera_info \\
      -p max_features:=300
"""


def main(args: list[str] | None = None) -> int:
    """``pearl_tracker`` console script: spin until SIGINT or SIGTERM, then exit 0.

    ``args`` as ``sys.argv`` (the program first; default ``sys.argv``). Exit 1 with one
    ``error:`` line for a bad parameter, parameter file or argument; ``-h`` / ``--help`` prints
    the usage and exits 0 without starting ROS.
    """
    return runner.run(args, 'pearl_tracker', lambda: USAGE.format(parameters=help_text()),
                      lambda files: TrackerNode(params_files=files))


if __name__ == '__main__':
    sys.exit(main())
