"""What every front end runs, ROS-free: settings, the per-message pipeline, the replay engine.

``pearl_node`` (:mod:`pearl_ros.ros.node`), ``pearl_replay`` (:mod:`pearl_ros.cli.replay`) and
``pearl_play`` build their :class:`~pearl_ros.pipeline.settings.Settings` with
:mod:`pearl_ros.pipeline.settings` and segment each message with
:class:`~pearl_ros.pipeline.messages.MessagePipeline`; :mod:`pearl_ros.pipeline.replay` runs a
recorded bag through it.
"""
