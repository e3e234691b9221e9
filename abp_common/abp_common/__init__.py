"""Shared ROS plumbing of the abp nodes (like nav2_common): no science here.

- `node_runner.run_node`: the init / spin / shutdown every node's `main()` shares.
- `lifecycle.ManagedNode`: the lifecycle node base class; it keeps its own registry of what
  each transition made (`entity_registry`) and undoes it with rclpy's public API.
- `tolerant_subscriptions`: subscriptions that drop, with a logged error, a message rclpy
  cannot convert instead of ending the node (`TolerantNode` for plain nodes).
- `qos`: the QoS profiles the graph's topics use.
- `names`: topic, service and action names, relative so that a graph runs under a namespace.
- `param_spec`: a ROS-free table type for a node's parameters (names, types, ranges, docs).
- `parameters.declare_all` / `read_all`: declare such a table on a node and read it back.
"""
