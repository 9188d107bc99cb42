"""``image_labels``: pearl_node draws its labels on the images of ``image_topic``, live, on a real
executor; the image pairing buffer; and ``launch/camera.launch.py``."""

from __future__ import annotations

import ast
from collections import Counter
from typing import Any

import cv2
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Log
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image, PointCloud, PointCloud2

from pearl_ros.bagio import cdr, decode
from pearl_ros.core.errors import InputError
from pearl_ros.ros.node import PearlNode, StampMatcher
from pearl_ros.ros.tracker_node import TrackerNode, features_message
from pearl_ros.tracking.draw import GREY, PALETTE, Overlay
from pearl_ros.tracking.image import array_to_image_fields
from pearl_ros.tracking.render import render_scene
from pearl_ros.tracking.tracker import FeatureTracker, TrackerConfig

from ros_harness import RELIABLE, REPO, Ros, header

SCENE = render_scene(5, frames=12, size=(240, 320))
STAMPS = [2_000_000_000 + k * 33_000_000 for k in range(len(SCENE.frames))]
MAX_FEATURES = 150  # the tracker's


def tinted_rgb(gray: np.ndarray) -> np.ndarray:
    """An rgb8 image whose channels differ, so that a swapped channel order shows."""
    return np.stack([gray, gray // 2, 255 - gray], axis=2).astype(np.uint8)


def image_msg(k: int, encoding: str = 'mono8') -> Image:
    pixels = SCENE.frames[k] if encoding == 'mono8' else tinted_rgb(SCENE.frames[k])
    return Image(header=header(STAMPS[k]), **array_to_image_fields(pixels, encoding))


def offline_features(k_last: int) -> list[PointCloud]:
    """The tracker's messages for frames 0..k_last, tracked here (no node)."""
    tracker = FeatureTracker(TrackerConfig(max_features=MAX_FEATURES))
    return [deserialize_message(cdr.serialize(features_message(
                header(STAMPS[k]), tracker.track(SCENE.frames[k], STAMPS[k]))), PointCloud)
            for k in range(k_last + 1)]


class Viewer:
    """A camera driver and a user of pearl_node's outputs, noting when each was published."""

    def __init__(self, ros: Ros, features: bool = False) -> None:
        self.ros = ros
        self.node = ros.node('viewer')
        self.images = self.node.create_publisher(Image, 'image', RELIABLE)
        self.features = (self.node.create_publisher(PointCloud, 'features', RELIABLE)
                         if features else None)
        self.labels: dict[int, tuple[PointCloud2, int]] = {}  # stamp -> (msg, published ns)
        self.drawn: dict[int, tuple[Image, int]] = {}
        self.diagnostics: list[dict[str, str]] = []
        self.logs: list[Log] = []
        self.node.create_subscription(PointCloud2, 'motion_labels', self._on_labels, RELIABLE)
        self.node.create_subscription(Image, 'image_labels', self._on_drawn, RELIABLE)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 50)
        rosout = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(Log, '/rosout', self._on_log, rosout)

    # The publisher's source timestamp says which message was published first, whatever order
    # the executor hands them to us in.
    def _on_labels(self, msg: PointCloud2, info: Any) -> None:
        self.labels[decode.stamp_ns(msg.header)] = (msg, info['source_timestamp'])

    def _on_drawn(self, msg: Image, info: Any) -> None:
        self.drawn[decode.stamp_ns(msg.header)] = (msg, info['source_timestamp'])

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.hardware_id.startswith(self.ros.ns):
                self.diagnostics.append({kv.key: kv.value for kv in status.values}
                                        | {'_message': status.message})

    def _on_log(self, msg: Log) -> None:
        if msg.name.startswith(self.ros.ns.strip('/') + '.') and msg.level == Log.WARN:
            self.logs.append(msg)

    def wait_for(self, node: PearlNode, images: int = 1) -> None:
        ns = self.ros.ns
        assert self.ros.spin_until(
            lambda: self.images.get_subscription_count() >= images
            and (self.features is None or self.features.get_subscription_count() > 0)
            and self.node.count_publishers(f'{ns}/image_labels') > 0
            and self.node.count_publishers(f'{ns}/motion_labels') > 0
            and node.count_subscribers(f'{ns}/image_labels') > 0
            and node.count_subscribers(f'{ns}/motion_labels') > 0, 10.0)

    def wait_drawn(self, k: int, timeout: float = 10.0) -> Image:
        assert self.ros.spin_until(lambda: STAMPS[k] in self.drawn, timeout), (
            f'no image_labels for frame {k}')
        return self.drawn[STAMPS[k]][0]

    def wait_labels(self, k: int, timeout: float = 10.0) -> None:
        assert self.ros.spin_until(lambda: STAMPS[k] in self.labels, timeout), (
            f'no motion_labels for frame {k}')

    def diagnostics_where(self, key: str, value: str) -> dict[str, str]:
        def found() -> dict[str, str] | None:
            return next((d for d in reversed(self.diagnostics) if d.get(key) == value), None)
        assert self.ros.spin_until(lambda: found() is not None, 5.0), self.diagnostics[-1:]
        result = found()
        assert result is not None
        return result


def drawn_array(msg: Image) -> np.ndarray:
    assert msg.encoding == 'bgr8'
    return np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.width, 3)


def drawing_node(ros: Ros, **parameters: Any) -> tuple[PearlNode, Viewer, Any]:
    """A pearl_node drawing on ``image`` (unbudgeted), a viewer that publishes images and
    features to it, once they see each other, and the viewer's ``publish`` of features."""
    node = ros.pearl(image_topic='image', budget_ms=0.0, **parameters)
    viewer = Viewer(ros, features=True)
    assert viewer.features is not None
    viewer.wait_for(node)
    return node, viewer, viewer.features.publish


def check_drawing(viewer: Viewer, frames: range, background: Any) -> None:
    """Each frame's image_labels: the input's header and size, published after its
    motion_labels, the input under the drawing, each motion in one colour of its own."""
    colour_of: dict[int, Counter[tuple[int, ...]]] = {}
    labelled = 0
    for k in frames:
        msg, drawn_at = viewer.drawn[STAMPS[k]]
        labels_msg, labelled_at = viewer.labels[STAMPS[k]]
        assert labelled_at < drawn_at, f'frame {k}: image_labels published before motion_labels'
        assert (msg.height, msg.width) == SCENE.frames[k].shape
        assert msg.header.frame_id == 'cam0'
        out = drawn_array(msg)
        assert np.mean(np.all(out == background(k), axis=2)) > 0.5  # the camera image beneath
        columns = decode.decode_fields(labels_msg, ('id', 'u', 'v', 'label'))
        labels = columns['label'].astype(int)
        uv = np.column_stack([columns['u'], columns['v']])
        # The corner holds the motion count: features under it are hidden.
        legend = Overlay()
        legend.draw(out, [], np.zeros((0, 2)), [])
        x1, y1 = legend.legend_box[2] + 40, legend.legend_box[3] + 4
        for (u, v), label in zip(np.rint(uv).astype(int), labels, strict=True):
            if u <= x1 and v <= y1:
                continue
            pixel = tuple(int(c) for c in out[v, u])
            if label >= 0:
                labelled += 1
                assert pixel in PALETTE, f'frame {k}: motion {label} drawn {pixel}'
                colour_of.setdefault(int(label), Counter())[pixel] += 1
            else:
                assert pixel == GREY or pixel in PALETTE  # a motion's dot may cover it
    assert labelled > 100 and len(colour_of) >= 2
    # Dots overlap where motions meet: a motion's colour is the one nearly all its dots have,
    # the same in every frame, and no other motion's.
    main = {}
    for label, colours in colour_of.items():
        colour, count = colours.most_common(1)[0]
        assert count >= 0.9 * colours.total(), f'motion {label} in several colours: {colours}'
        main[label] = colour
    assert len(set(main.values())) == len(main)


def test_the_camera_chain_draws_every_frame_after_publishing_its_labels(ros: Ros) -> None:
    # camera -> pearl_tracker -> pearl_node, the image going to both: images come first here.
    tracker = ros.add(TrackerNode(context=ros.context, namespace=ros.ns, parameter_overrides=[
        Parameter('max_features', value=MAX_FEATURES), Parameter('qos', value='reliable'),
        Parameter('qos_depth', value=5)]))
    node = ros.pearl(image_topic='image', budget_ms=0.0)
    viewer = Viewer(ros)
    viewer.wait_for(node, images=2)
    assert ros.spin_until(lambda: tracker.count_subscribers(f'{ros.ns}/features') > 0)
    for k in range(len(STAMPS)):
        viewer.images.publish(image_msg(k))
        viewer.wait_drawn(k)
        viewer.wait_labels(k)
    assert sorted(viewer.drawn) == STAMPS
    check_drawing(viewer, range(len(STAMPS)),
                  lambda k: np.repeat(SCENE.frames[k][:, :, None], 3, axis=2))
    values = viewer.diagnostics_where('annotated images', str(len(STAMPS)))
    assert values['images without labels (dropped)'] == '0'
    assert values['labels without image (dropped)'] == '0'


def test_labels_that_come_before_their_image_wait_for_it(ros: Ros) -> None:
    node, viewer, send = drawing_node(ros)
    messages = offline_features(len(STAMPS) - 1)
    for k, features in enumerate(messages):
        if k % 2:  # odd frames: labels first, then the image
            send(features)
            viewer.wait_labels(k)
            assert STAMPS[k] not in viewer.drawn
            viewer.images.publish(image_msg(k, 'rgb8'))
        else:  # even frames: the image waits for the labels
            viewer.images.publish(image_msg(k, 'rgb8'))
            assert ros.spin_until(lambda k=k: node.stats.images == k + 1)
            send(features)
        viewer.wait_drawn(k)
    check_drawing(viewer, range(len(STAMPS)),
                  lambda k: cv2.cvtColor(tinted_rgb(SCENE.frames[k]), cv2.COLOR_RGB2BGR))


def test_images_and_labels_without_a_partner_are_dropped_and_counted(ros: Ros) -> None:
    node, viewer, send = drawing_node(ros)
    messages = offline_features(4)
    viewer.images.publish(image_msg(0))  # no features for it: the tracker skipped it
    send(messages[1])  # no image for it
    viewer.wait_labels(1)
    assert ros.spin_until(lambda: node.stats.images == 1)
    viewer.images.publish(image_msg(2))
    send(messages[2])
    viewer.wait_drawn(2)
    values = viewer.diagnostics_where('annotated images', '1')
    assert values['images without labels (dropped)'] == '1'
    assert values['labels without image (dropped)'] == '1'
    assert values['images waiting'] == values['labels waiting'] == '0'
    assert sorted(viewer.drawn) == [STAMPS[2]]


def test_a_stamp_gone_back_starts_the_drawing_afresh(ros: Ros) -> None:
    # A bag replayed in a loop: labels at an earlier stamp empty the window; the image of that
    # stamp is still drawn, and what waited for a later stamp is dropped.
    node, viewer, send = drawing_node(ros)
    messages = offline_features(3)
    for k in (0, 1, 2):
        viewer.images.publish(image_msg(k))
        send(messages[k])
        viewer.wait_drawn(k)
    viewer.images.publish(image_msg(3))  # its labels never come: the loop restarts
    viewer.drawn.clear()
    viewer.images.publish(image_msg(0))
    assert ros.spin_until(lambda: node.stats.images == 5)
    send(messages[0])
    viewer.wait_drawn(0)
    values = viewer.diagnostics_where('annotated images', '4')
    assert values['window resets (stamp went back)'] == '1'
    assert values['images without labels (dropped)'] == '1'
    assert values['images waiting'] == '0'


def test_a_bad_image_is_warned_about_and_counted_and_the_node_goes_on(ros: Ros) -> None:
    node, viewer, send = drawing_node(ros)
    messages = offline_features(3)
    for k in (0, 1):  # an encoding we do not read, twice in a row: one warning
        viewer.images.publish(Image(header=header(STAMPS[k]), height=240, width=320,
                                    encoding='32FC1', step=320 * 4, data=bytes(240 * 320 * 4)))
    for k in (0, 1):
        send(messages[k])
        viewer.wait_labels(k)
    short = image_msg(2)
    short.data = bytes(short.data)[:1000]  # a supported encoding, too little data
    viewer.images.publish(short)
    send(messages[2])
    viewer.wait_labels(2)
    viewer.images.publish(image_msg(3))
    send(messages[3])
    viewer.wait_drawn(3)
    values = viewer.diagnostics_where('annotated images', '1')  # a status after the last draw
    assert values['images refused (encoding, malformed)'] == '3'
    assert ros.spin_until(lambda: viewer.logs, 5.0)
    warnings = [m.msg for m in viewer.logs if "'32FC1'" in m.msg]
    assert len(warnings) == 1 and '\n' not in warnings[0]
    assert sorted(viewer.drawn) == [STAMPS[3]] and sorted(viewer.labels) == STAMPS[:4]


# A camera for the rendered frames (320 x 240): focal length and principal point, px.
FOCAL_PX, CENTRE_PX = 300.0, (160.0, 120.0)


def normalised_only(msg: PointCloud) -> PointCloud:
    """The message as a front end that sends normalised coordinates alone would: its points
    (pixels, from a tracker without camera_info) taken to the normalised coordinates of the
    camera of FOCAL_PX and CENTRE_PX, and no u_of_point, v_of_point channels."""
    for point in msg.points:
        point.x = (point.x - CENTRE_PX[0]) / FOCAL_PX
        point.y = (point.y - CENTRE_PX[1]) / FOCAL_PX
    msg.channels = [c for c in msg.channels if c.name not in ('u_of_point', 'v_of_point')]
    return msg


@pytest.mark.parametrize('intrinsics', [False, True])
def test_normalised_features_are_drawn_with_the_intrinsics_or_warned_about(
        ros: Ros, intrinsics: bool) -> None:
    # With the camera's intrinsics the normalised points are drawn where the tracker found them.
    camera = ({'camera_fx': FOCAL_PX, 'camera_fy': FOCAL_PX, 'camera_cx': CENTRE_PX[0],
               'camera_cy': CENTRE_PX[1]} if intrinsics else {})
    node, viewer, send = drawing_node(ros, **camera)
    frames = range(4)
    for k, features in zip(frames, offline_features(frames[-1]), strict=True):
        viewer.images.publish(image_msg(k))
        send(normalised_only(features))
        viewer.wait_labels(k)
    if intrinsics:
        viewer.wait_drawn(frames[-1])
        check_drawing(viewer, frames, lambda k: np.repeat(SCENE.frames[k][:, :, None], 3, axis=2))
        assert not any('normalised' in m.msg for m in viewer.logs)
        return
    assert ros.spin_until(lambda: any('normalised' in m.msg for m in viewer.logs), 5.0)
    warnings = [m.msg for m in viewer.logs if 'normalised' in m.msg]
    assert len(warnings) == 1 and 'camera_info_topic' in warnings[0]
    assert not viewer.drawn and sorted(viewer.labels) == STAMPS[:len(frames)]


def test_without_image_topic_there_is_no_image_subscription_nor_output(ros: Ros) -> None:
    node = ros.pearl()
    assert node.get_parameter('image_topic').value == ''
    assert not any(topic.endswith('image_labels') for topic, _ in
                   node.get_publisher_names_and_types_by_node(node.get_name(), ros.ns))
    assert 'annotated images' not in {kv.key for kv in node.diagnostics().status[0].values}


def test_image_topic_is_read_only_and_a_bad_name_is_refused(ros: Ros) -> None:
    node = ros.pearl(image_topic='/camera/image_raw')
    result = node.set_parameters([Parameter('image_topic', value='other')])[0]
    assert not result.successful and 'read-only' in result.reason
    subscriptions = node.get_subscriber_names_and_types_by_node(node.get_name(), ros.ns)
    assert ('/camera/image_raw', ['sensor_msgs/msg/Image']) in subscriptions
    with pytest.raises(InputError, match=r"^image_topic 'bad topic!' is not a valid topic name"):
        ros.pearl(image_topic='bad topic!')


def test_the_matcher_pairs_by_stamp_whichever_comes_first_and_bounds_what_waits() -> None:
    matcher = StampMatcher(depth=3)
    assert matcher.add('image', 10, 'i10') is None
    assert matcher.add('labels', 10, 'l10') == ('i10', 'l10')
    assert matcher.add('labels', 20, 'l20') is None
    assert matcher.add('image', 20, 'i20') == ('i20', 'l20')  # (image, labels) either way
    for stamp in (30, 40, 50, 60):  # images whose labels never come
        assert matcher.add('image', stamp, stamp) is None
    assert matcher.waiting('image') == 3 and matcher.dropped['image'] == 1
    assert matcher.overflows == 1
    # A pair at 60 ends the wait of everything older.
    assert matcher.add('labels', 45, 'l45') is None
    assert matcher.add('labels', 60, 'l60') == (60, 'l60')
    assert matcher.waiting('image') == matcher.waiting('labels') == 0
    assert matcher.dropped == {'image': 3, 'labels': 1}


def test_the_camera_launch_file_chains_the_tracker_and_the_node_on_one_image() -> None:
    # launch and launch_ros are not on PyPI: check what the file says, not what it does.
    tree = ast.parse((REPO / 'launch' / 'camera.launch.py').read_text())
    functions = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
    assert 'generate_launch_description' in functions
    arguments = {n.args[0].value for n in ast.walk(tree) if isinstance(n, ast.Call)
                 and getattr(n.func, 'id', '') == 'DeclareLaunchArgument'}
    assert {'image', 'camera_info', 'namespace', 'params_file', 'pose_topic'} <= arguments
    nodes = {}
    for call in ast.walk(tree):
        if isinstance(call, ast.Call) and getattr(call.func, 'id', '') == 'Node':
            keywords = {k.arg: k.value for k in call.keywords}
            nodes[ast.literal_eval(keywords['executable'])] = keywords
    assert set(nodes) == {'pearl_tracker', 'pearl_node'}
    for keywords in nodes.values():
        assert {'package', 'namespace', 'parameters', 'remappings'} <= set(keywords)
        assert ast.literal_eval(keywords['package']) == 'pearl_ros'
        assert ast.unparse(keywords['namespace']) == "LaunchConfiguration('namespace')"

    def remaps(executable: str) -> dict[str, str]:
        """Remapped name -> the launch argument (or text) it goes to."""
        out = {}
        for pair in nodes[executable]['remappings'].elts:
            source, target = pair.elts
            out[ast.literal_eval(source)] = ast.unparse(target)
        return out
    tracker, pearl = remaps('pearl_tracker'), remaps('pearl_node')
    assert tracker == {'image': "LaunchConfiguration('image')",
                       'camera_info': "LaunchConfiguration('camera_info')"}
    # the tracker's output is the node's input: both keep the relative name `features`
    assert 'features' not in tracker and 'features' not in pearl
    # pearl_node draws on the camera's image: image_topic is the image launch argument
    parameters = ast.unparse(nodes['pearl_node']['parameters'])
    assert "'image_topic': LaunchConfiguration('image')" in parameters
    # with pose_topic, the node's intrinsics come from the tracker's own camera_info
    assert "'pose_topic': LaunchConfiguration('pose_topic')" in parameters
    assert "'camera_info_topic': LaunchConfiguration('camera_info')" in parameters
    assert "LaunchConfiguration('params_file')" in parameters
    assert REPO.joinpath('setup.py').read_text().count("glob('launch/*.launch.py')") == 1


def test_a_live_camera_at_15_hz_gets_labels_and_an_annotated_image_for_nearly_every_frame(
        ros: Ros) -> None:
    # Issue 16's live case: a 640 x 480 camera publishing on its own clock at 15 Hz through
    # pearl_tracker and pearl_node on one executor, nobody waiting for answers between frames.
    scene = render_scene(7, frames=45, size=(480, 640))
    stamps = [3_000_000_000 + k * 66_666_667 for k in range(len(scene.frames))]
    ros.add(TrackerNode(context=ros.context, namespace=ros.ns, parameter_overrides=[
        Parameter('qos', value='reliable'), Parameter('qos_depth', value=5)]))
    node = ros.pearl(image_topic='image')  # default budget, as a user runs it
    viewer = Viewer(ros)
    viewer.wait_for(node, images=2)
    assert ros.spin_until(lambda: node.count_publishers(f'{ros.ns}/features') > 0)
    sent: list[int] = []

    def publish() -> None:
        if len(sent) < len(stamps):
            k = len(sent)
            pixels = scene.frames[k]
            viewer.images.publish(Image(header=header(stamps[k]),
                                        **array_to_image_fields(pixels, 'mono8')))
            sent.append(k)

    camera = viewer.node.create_timer(1.0 / 15.0, publish)
    assert ros.spin_until(lambda: len(sent) == len(stamps), 10.0)
    camera.cancel()
    ros.spin_until(lambda: len(viewer.drawn) == len(stamps), 3.0)
    answered = [s for s in stamps if s in viewer.labels and s in viewer.drawn]
    assert len(answered) >= 0.95 * len(stamps), (
        f'{len(answered)} of {len(stamps)} frames got labels and an annotated image')
    assert all(viewer.drawn[s][0].width == 640 for s in answered)
