"""The camera front end, ROS-free: a KLT feature tracker (:mod:`.tracker`), ``sensor_msgs/Image``
<-> numpy (:mod:`.image`) and rendered clips of known motion for tests and demos (:mod:`.render`).

Depends on numpy, OpenCV and ``pearl_ros.core`` (configuration fields and errors) only.
"""
