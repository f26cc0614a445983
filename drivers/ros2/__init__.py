"""ROS 2 without a ROS install: its messages as Cyclone DDS types and CDR bytes, a DDS node that is a ROS 2 node to
the others, and ROS 2 bags as MCAP files (docs/ros2.md). Needs the ``ros2`` extra (cyclonedds, mcap).

- :mod:`drivers.ros2.messages`: the message and service types with ROS 2's DDS names, and their definitions;
- :mod:`drivers.ros2.cdr`: batches of WrenchStamped as CDR bytes in one numpy operation;
- :mod:`drivers.ros2.node`: :class:`~drivers.ros2.node.Ros2Node` (topics, QoS, the Trigger service, discovery);
- :mod:`drivers.ros2.bag`: :class:`~drivers.ros2.bag.BagWriter` (MCAP, ``ros2`` profile).
"""
