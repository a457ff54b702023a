# MorphspaceMesh: a MeshInstance that plays a morphspace motion space streamed from a server.
#
# Add it to a scene (the plugin registers it; or attach this script to a MeshInstance), set
# url and space (or graph, and optionally node, for a motion graph), and run: it connects,
# builds the mesh from the topology, replaces the vertices with every frame and, with
# follow_root, sets its own transform (relative to its parent) to the frame's root transform.
# Game scripts steer it with set_param / set_params and listen to its signals; on a graph they
# call action(node, params, budget) and follow current_node, target_node and progress
# (node_changed when the node shown changes). With pull_mode on it asks for frames on the
# engine's clock instead (hello rate 0, one pull at a time at pull_time, which advances by
# delta * time_scale).
extends MeshInstance

const Client = preload("res://addons/morphspace/client.gd")
const FlatShader = preload("res://addons/morphspace/flat_normals.shader")

signal connected()
signal disconnected(reason, retry_in)
signal topology_received(topology)
signal frame_applied(frame)      # a frame is on the mesh; frame.update_usec is the mesh update's cost
signal frame_pulled(frame)       # a frame answering pull() (applied too in pull_mode)
signal error_received(error)     # {code, message, ref, seq}
signal notice_received(notice)   # {code, message, seq}: also an action's planned / queued
signal node_changed(node, previous)  # graphs: the applied frames' node changed (previous "" at first)

export(String) var url = "ws://127.0.0.1:8000/v1/stream"
export(String) var space = ""
export(String) var graph = ""    # a motion graph instead of a space
export(String) var node = ""     # with graph: the start node ("": the graph's first cyclic node)
export(String, "f32", "q16") var codec = "f32"
export(float, 0, 120) var rate = 60.0
export(String, "hybrid", "linear", "nonlinear") var mode = "hybrid"
export(float, 0, 10) var smoothing = 0.25
export(int, 0, 64) var window = 0
export(Dictionary) var params = {}
export(bool) var autostart = true
export(bool) var auto_reconnect = true
export(bool) var follow_root = true
export(bool) var pull_mode = false
export(float) var time_scale = 1.0
export(bool) var flat_shading_material = true  # used when material_override is empty

var client = Client.new()
var pull_time = 0.0       # seconds on the engine's clock (pull_mode)
var frames_applied = 0
var last_frame = null     # the last frame applied (its vertices are the mesh's)
var current_node = ""     # graphs: the node of the last frame applied (during a blend: the one being left)
var target_node = null    # graphs: where a planned or blending transition goes, else null
var progress = null       # graphs: 0..1 across a blend, else null
var _indices = null
var _pull_id = -1


func _ready():
	client.connect("connected", self, "_forward", ["connected"])
	client.connect("disconnected", self, "_on_disconnected")
	client.connect("topology_received", self, "_on_topology")
	client.connect("frame_received", self, "_on_frame")
	client.connect("pull_received", self, "_on_pull")
	client.connect("error_received", self, "_on_error")
	client.connect("notice_received", self, "_forward1", ["notice_received"])
	if material_override == null and flat_shading_material:
		var material = ShaderMaterial.new()
		material.shader = FlatShader
		material_override = material
	if autostart and (space != "" or graph != ""):
		start()


func _exit_tree():
	client.stop()


func _notification(what):
	# Let go of the mesh before the node is freed: otherwise, at the engine's quit, the visual
	# server can look at this instance's freed mesh ("mesh_get_surface_count: Condition !m",
	# seen headless with a node made by .new() and stopped before get_tree().quit()).
	if what == NOTIFICATION_PREDELETE:
		mesh = null


func start():
	# Connect with the exported settings (again, if connected).
	client.url = url
	client.space = space
	client.graph = graph
	client.node = node
	client.codec = codec
	client.rate = 0.0 if pull_mode else rate
	client.mode = mode
	client.smoothing = smoothing
	client.window = window
	client.params = params.duplicate()
	client.auto_reconnect = auto_reconnect
	client.start()


func stop():
	client.stop()


func _process(delta):
	client.poll(delta)
	if pull_mode:
		pull_time += delta * time_scale
		if client.is_open() and client.pending_pulls() == 0:
			_pull_id = client.pull(null, pull_time)


# ------------------------------------------------------------------ for game scripts

func set_param(name, value, immediate = false):
	# Request one parameter (e.g. set_param("speed", 2.0)); returns the message's seq: frames
	# with ack >= it reflect the request.
	return set_params({name: value}, immediate)


func set_params(values, immediate = false):
	# On a graph: the node shown's (during a blend: its target's); params keeps the start node's.
	var seq = client.set_params(values, immediate)
	params = client.params.duplicate()
	return seq


func get_param(name):
	# The value last requested (on a graph: of the node shown).
	var state = client.graph_state
	if graph != "" and state.node_params.has(current_node):
		return state.node_params[current_node].get(name)
	return client.params.get(name)


func parameters():
	# The space's parameters from the topology: [{name, unit, min, max, default, value}], or [];
	# on a graph, the node shown's (value: as the topology had it).
	if graph != "" and client.graph_state.nodes.has(current_node):
		return client.graph_state.nodes[current_node]["parameters"]
	return client.topology["parameters"] if client.topology != null else []


func action(node_name, node_params = {}, budget = null):
	# On a graph: go to node_name (e.g. action("jump", {"jump_height": 0.5})), within budget
	# seconds if given; returns the message's seq. The server's planned / queued notice comes as
	# notice_received; node_changed follows the frames.
	return client.action(node_name, node_params, budget)


func graph_nodes():
	# The graph's nodes from the topology: [{name, space, cyclic, return_to, parameters}], or [].
	var out = []
	if client.topology != null and client.topology.get("nodes") != null:
		out = client.topology["nodes"]
	return out


func graph_edges():
	# The graph's allowed transitions from the topology: [{from, to}], or [].
	var out = []
	if client.topology != null and client.topology.get("edges") != null:
		out = client.topology["edges"]
	return out


func set_mode(new_mode):
	mode = new_mode
	return client.set_mode(new_mode)


func pause():
	return client.pause()


func resume():
	return client.resume()


func seek(phase):
	return client.seek(phase)


func reset_root():
	pull_time = 0.0
	return client.reset()


func pull(pull_params = null, time = null, phase = null):
	# One frame at these parameters and time or phase (emitted as frame_pulled); returns its id.
	return client.pull(pull_params, time, phase)


# ------------------------------------------------------------------ the mesh

func _on_topology(topology):
	_indices = topology["indices"]
	mesh = ArrayMesh.new()
	last_frame = null
	current_node = ""
	target_node = null
	progress = null
	emit_signal("topology_received", topology)


func _on_frame(frame):
	if not pull_mode:
		_apply(frame)


func _on_pull(frame):
	emit_signal("frame_pulled", frame)
	if pull_mode and frame["pull_id"] == _pull_id:
		_apply(frame)


func _apply(frame):
	var started = OS.get_ticks_usec()
	var arrays = []
	arrays.resize(Mesh.ARRAY_MAX)
	arrays[Mesh.ARRAY_VERTEX] = frame["vertices"]
	arrays[Mesh.ARRAY_INDEX] = _indices
	var array_mesh = mesh
	if array_mesh.get_surface_count() > 0:
		array_mesh.surface_remove(0)
	array_mesh.add_surface_from_arrays(Mesh.PRIMITIVE_TRIANGLES, arrays)
	if follow_root:
		transform = frame["transform"]
	frame["update_usec"] = OS.get_ticks_usec() - started
	last_frame = frame
	frames_applied += 1
	var previous = current_node
	if frame.get("node") != null:
		current_node = frame["node"]
		target_node = frame.get("target")
		progress = frame.get("progress")
	if current_node != previous:
		emit_signal("node_changed", current_node, previous)
	emit_signal("frame_applied", frame)


func _on_disconnected(reason, retry_in):
	emit_signal("disconnected", reason, retry_in)


func _on_error(error):
	if error.get("ref") == "pull" and error.get("seq") == _pull_id:
		_pull_id = -1
	emit_signal("error_received", error)


func _forward(signal_name):
	emit_signal(signal_name)


func _forward1(value, signal_name):
	emit_signal(signal_name, value)
