# A motion graph through the add-on, for tests/engine_clients/test_godot.py (run as the scene
# res://graph.tscn).
#
# User arguments: --out=DIR --url=... --graph=NAME --node=START --param=NAME --value=X (the start
# node's parameter) --steer=Z (set_param(NAME, Z) after N / 2 frames) --codec=f32|q16 --before=N
# (frames before the action) --action=NODE
# --action-param=NAME --action-value=Y [--budget=SECONDS] --after=M (frames on a cyclic node after
# the action's node) --timeout=S.
# A MorphspaceMesh streams the graph from START, takes N frames, calls action(NODE, {NAME: Y})
# (within the budget, if given) and goes on until the frames have shown NODE and then M frames
# of a cyclic node. Every applied frame is written to DIR/records.msgpack (its fields, the
# vertices the mesh holds, and the node's current_node / target_node / progress after it);
# DIR/summary.msgpack holds the graph's nodes and edges as graph_nodes() / graph_edges() give
# them, the topology's quantisation_error, the action's seq, the notices and every node_changed.
# Exit code 0, or 1 with DIR/error.txt.
extends Node

const MorphspaceMesh = preload("res://addons/morphspace/morphspace_mesh.gd")
const Msgpack = preload("res://addons/morphspace/msgpack.gd")

var options = {}
var mesh_node = null
var records = File.new()
var deadline = 0
var applied = 0
var action_seq = -1
var reached = false       # the frames have shown the action's node
var after = 0             # frames on a cyclic node since then
var done = false
var summary = {"nodes": [], "edges": [], "notices": [], "changes": [], "topologies": 0}


func _ready():
	for arg in OS.get_cmdline_args():
		if arg.begins_with("--") and "=" in arg:
			var cut = arg.find("=")
			options[arg.substr(2, cut - 2)] = arg.substr(cut + 1)
	Engine.target_fps = 60
	deadline = OS.get_ticks_msec() + int(options.get("timeout", "60").to_float() * 1000)
	if records.open(options["out"].plus_file("records.msgpack"), File.WRITE) != OK:
		_fail("cannot write %s" % options["out"])
		return
	mesh_node = MorphspaceMesh.new()
	mesh_node.url = options["url"]
	mesh_node.graph = options["graph"]
	mesh_node.node = options["node"]
	mesh_node.codec = options["codec"]
	mesh_node.mode = "linear"
	mesh_node.rate = 30.0
	mesh_node.smoothing = 0.0
	mesh_node.params = {options["param"]: options["value"].to_float()}
	mesh_node.connect("topology_received", self, "_on_topology")
	mesh_node.connect("frame_applied", self, "_on_frame")
	mesh_node.connect("node_changed", self, "_on_node_changed")
	mesh_node.connect("notice_received", self, "_on_notice")
	mesh_node.connect("error_received", self, "_on_error")
	add_child(mesh_node)


func _process(_delta):
	if OS.get_ticks_msec() > deadline:
		_fail("timed out: %d frames, action seq %d, reached %s, changes %s"
				% [applied, action_seq, reached, summary["changes"]])


func _on_topology(topology):
	summary["topologies"] += 1
	summary["quantisation_error"] = topology["quantisation_error"]
	summary["nodes"] = mesh_node.graph_nodes()
	summary["edges"] = mesh_node.graph_edges()


func _on_node_changed(new_node, previous):
	summary["changes"].append({"node": new_node, "previous": previous, "frame": applied})


func _on_notice(notice):
	summary["notices"].append(notice)


func _on_frame(frame):
	if done:
		return
	applied += 1
	var vertices = mesh_node.mesh.surface_get_arrays(0)[Mesh.ARRAY_VERTEX]
	var record = {"vertices": var2bytes(vertices).subarray(8, 8 + 12 * vertices.size() - 1),
			"current_node": mesh_node.current_node, "target_node": mesh_node.target_node,
			"progress_property": mesh_node.progress, "get_param": mesh_node.get_param(options["param"])}
	for key in ["seq", "ack", "time", "phase", "mode", "node", "target", "progress", "requested", "realised",
			"requested_params", "realised_params", "weights", "root", "heading", "finished"]:
		record[key] = frame.get(key)
	records.store_buffer(Msgpack.encode(record))
	if applied == int(options["before"]) / 2:
		summary["steer_seq"] = mesh_node.set_param(options["param"], options["steer"].to_float())
	if applied == int(options["before"]):
		var budget = options["budget"].to_float() if options.has("budget") else null
		action_seq = mesh_node.action(options["action"], {options["action-param"]: options["action-value"].to_float()},
				budget)
		summary["action_seq"] = action_seq
	if action_seq < 0 or frame["ack"] < action_seq:
		return
	if frame["node"] == options["action"]:
		reached = true
	elif reached and _cyclic(frame["node"]):
		after += 1
		if after >= int(options["after"]):
			_finish()


func _cyclic(name):
	for n in mesh_node.graph_nodes():
		if n["name"] == name:
			return n["cyclic"]
	return false


func _on_error(error):
	_fail("server error %s: %s" % [error.get("code"), error.get("message")])


func _finish():
	done = true
	records.close()
	var file = File.new()
	file.open(options["out"].plus_file("summary.msgpack"), File.WRITE)
	file.store_buffer(Msgpack.encode(summary))
	file.close()
	mesh_node.stop()
	set_process(false)
	get_tree().quit(0)


func _fail(message):
	if done:
		return
	done = true
	records.close()
	var file = File.new()
	file.open(options["out"].plus_file("error.txt"), File.WRITE)
	file.store_string(message + "\n")
	file.close()
	set_process(false)
	get_tree().quit(1)
