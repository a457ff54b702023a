# What a client knows of a motion graph stream (docs/protocol.md, "Motion graphs"): the
# topology's nodes and edges, every node's parameters last requested, and the last emitted
# frame's node, target and progress. client.gd holds one as graph_state; empty on a space.
extends Reference

var nodes = {}                # node name -> {name, space, cyclic, return_to, parameters}
var edges = []                # [{from, to}]: the allowed transitions
var node_params = {}          # node name -> {parameter: value last requested}
var playing_node = ""         # the node of the last emitted frame (during a blend: the one being left)
var target_node = null        # where a planned or blending transition goes, else null
var progress = null           # 0..1 across a blend, else null
var start_node = ""           # the node the last hello started at (its first frame's)


func read_topology(topology):
	# A new topology (a hello's answer): its nodes and edges, their parameters' values.
	nodes = {}
	edges = []
	start_node = ""
	clear_frame()
	if topology.get("graph") == null:
		return
	for n in topology["nodes"]:
		nodes[n["name"]] = n
		var values = {}
		for p in n["parameters"]:
			values[p["name"]] = p["value"]
		node_params[n["name"]] = values
	edges = topology["edges"]


func clear_frame():
	playing_node = ""
	target_node = null
	progress = null


func parameter_names(node_name, fallback):
	# The node's parameter names in the order of a frame's requested / realised (fallback: unknown node).
	if not nodes.has(node_name):
		return fallback
	var names = []
	for p in nodes[node_name]["parameters"]:
		names.append(p["name"])
	return names


func steered_node():
	# The node a params message steers: the one shown, during a blend its target.
	if target_node != null and progress != null:
		return target_node
	return playing_node


func remember(node_name, values):
	if not node_params.has(node_name):
		node_params[node_name] = {}
	for name in values:
		node_params[node_name][name] = values[name]


func follow(frame):
	# Keep a graph frame's node, target and progress; returns the previous node when the node
	# shown changed ("" for the first frame after a topology), else null.
	target_node = frame.get("target")
	progress = frame.get("progress")
	var previous = playing_node
	playing_node = frame["node"]
	if start_node == "":
		start_node = playing_node
	return previous if playing_node != previous else null
