"""The message contract that needs no rclpy: the REP 105 state <-> Odometry mapping
(:mod:`.rep105`), orientations (:mod:`.orientation`) and one QoS profile per topic
(:mod:`.qos_specs`)."""
