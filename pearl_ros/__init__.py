"""pearl_ros: online multi-body motion segmentation with PEaRL (Isack & Boykov, IJCV 2012).

Layers run one way: ``core`` (numpy, scipy, maxflow) <- ``online`` (streaming) and ``bagio``
(rosbags) <- ``pipeline`` (the per-message pipeline and the replay engine) <- ``ros`` and
``cli``. Only ``pearl_ros.ros`` imports rclpy.
"""

__version__ = '0.1.0'
