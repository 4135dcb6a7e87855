"""What every node shares: :mod:`.executor` (the executor, signals, the exit report),
:mod:`.startup` (quiet Ctrl-C while importing), :mod:`.exit_watchdog`, :mod:`.native_preload`,
:mod:`.params` (declaration with descriptors), :mod:`.qos` (the rclpy profiles),
:mod:`.conversions` (states and commands to and from messages) and :mod:`.markers` (RViz)."""
