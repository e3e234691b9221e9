"""Shared ROS plumbing of the abp nodes (like nav2_common): no science here.

- `node_runner.run_node`: the init / spin / shutdown every node's `main()` shares.
- `qos`: the QoS profiles the graph's topics use.
- `names`: topic, service and action names, relative so that a graph runs under a namespace.
- `param_spec`: a ROS-free table type for a node's parameters (names, types, ranges, docs).
- `parameters.declare_all` / `read_all`: declare such a table on a node and read it back.
"""
