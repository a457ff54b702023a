# Reconnecting, for tests/engine_clients/test_godot.py (run as the scene res://reconnect.tscn).
#
# User arguments: --out=DIR --url=... --space=NAME --param=NAME --value=X --frames=N --timeout=S.
# A MorphspaceMesh connects (retrying until the test starts the server), steers the parameter to
# X, takes N frames, writes DIR/first.txt and waits: the test restarts the server. After the
# add-on has reconnected and taken N more frames, DIR/summary.msgpack holds every disconnect
# (reason, retry_in), the topologies seen and the frames' requested values and acks.
extends Node

const MorphspaceMesh = preload("res://addons/morphspace/morphspace_mesh.gd")
const Msgpack = preload("res://addons/morphspace/msgpack.gd")

var options = {}
var node = null
var deadline = 0
var steer_seq = -1
var topologies = 0
var frames = [[], []]
var disconnects = []


func _ready():
	for arg in OS.get_cmdline_args():
		if arg.begins_with("--") and "=" in arg:
			var cut = arg.find("=")
			options[arg.substr(2, cut - 2)] = arg.substr(cut + 1)
	Engine.target_fps = 60
	deadline = OS.get_ticks_msec() + int(options.get("timeout", "60").to_float() * 1000)
	node = MorphspaceMesh.new()
	node.url = options["url"]
	node.space = options["space"]
	node.rate = 30.0
	node.smoothing = 0.0
	node.client.reconnect_min = 0.2
	node.client.reconnect_max = 1.0
	node.connect("topology_received", self, "_on_topology")
	node.connect("frame_applied", self, "_on_frame")
	node.connect("disconnected", self, "_on_disconnected")
	add_child(node)


func _process(_delta):
	if OS.get_ticks_msec() > deadline:
		_write("error.txt", ("timed out: %d topologies, frames %d + %d, disconnects %s"
				% [topologies, frames[0].size(), frames[1].size(), disconnects]).to_utf8())
		set_process(false)
		get_tree().quit(1)


func _on_topology(_topology):
	topologies += 1
	if topologies == 1:
		steer_seq = node.set_param(options["param"], options["value"].to_float(), true)


func _on_frame(frame):
	var connection = topologies - 1
	if connection > 1 or (connection == 0 and frame["ack"] < steer_seq):
		return
	var wanted = int(options["frames"])
	if frames[connection].size() >= wanted:
		return
	frames[connection].append({"seq": frame["seq"], "ack": frame["ack"], "requested": frame["requested"]})
	if frames[connection].size() == wanted:
		if connection == 0:
			_write("first.txt", "ok".to_utf8())
		else:
			_write("summary.msgpack", Msgpack.encode({"topologies": topologies, "frames": frames,
					"disconnects": disconnects, "steer_seq": steer_seq}))
			node.stop()
			get_tree().quit(0)


func _on_disconnected(reason, retry_in):
	disconnects.append({"reason": reason, "retry_in": retry_in, "after_topologies": topologies})


func _write(name, bytes):
	var file = File.new()
	file.open(options["out"].plus_file(name), File.WRITE)
	file.store_buffer(bytes)
	file.close()
