# Drives the morphspace add-on headless for tests/engine_clients/test_godot.py.
#
# User arguments (after "--"): --out=DIR --url=ws://... --space=NAME --param=NAME
# --values=A,B (the parameter at the start and after the steer) --frames=N (streamed frames per
# codec) --pulls=T1,T2,... (times pulled per codec, at --pull-value) --engine-frames=M (frames
# pulled on the engine's clock) --engine-fps=F --timeout=S --record-vertices=1 (0: timings only,
# no vertices and no read-back of the mesh: benchmarks/godot_client.py).
# For each codec (f32, q16): a MorphspaceMesh streams N frames (steered half way with
# set_param), then pulls; then a MorphspaceMesh in pull_mode takes M frames. Every frame is
# written to DIR/records.msgpack (one msgpack map per frame, written with the add-on's encoder):
# its fields, the vertices the mesh holds after it was applied (or the decoded ones for pulled
# frames that are not applied), the node's transform, decode and mesh update times.
# DIR/summary.msgpack ends the run; exit code 0, or 1 with DIR/error.txt.
extends Node

const MorphspaceMesh = preload("res://addons/morphspace/morphspace_mesh.gd")
const Msgpack = preload("res://addons/morphspace/msgpack.gd")

var options = {}
var out_dir = ""
var records = File.new()
var deadline = 0
var codecs = ["f32", "q16"]
var stage = -1
var node = null
var streamed = 0
var steer_seq = -1
var pulls_sent = false
var pulls_received = 0
var first_usec = 0
var received = 0
var received_first = 0
var superseded = 0
var server_dropped = 0
var last_usec = 0
var summary = {"codecs": {}, "errors": [], "disconnects": []}


func _ready():
	for arg in OS.get_cmdline_args():
		if arg.begins_with("--") and "=" in arg:
			var cut = arg.find("=")
			options[arg.substr(2, cut - 2)] = arg.substr(cut + 1)
	out_dir = options.get("out", "")
	if out_dir == "":
		push_error("no --out=DIR")
		get_tree().quit(1)
		return
	Engine.target_fps = int(options.get("engine-fps", "60"))
	deadline = OS.get_ticks_msec() + int(float(options.get("timeout", "60")) * 1000)
	if records.open(out_dir.plus_file("records.msgpack"), File.WRITE) != OK:
		_fail("cannot write %s" % out_dir)
		return
	_next_stage()


func _values():
	var values = []
	for text in options["values"].split(","):
		values.append(text.to_float())
	return values


func _next_stage():
	if node != null:
		node.stop()
		node.queue_free()
		node = null
	stage += 1
	streamed = 0
	steer_seq = -1
	pulls_sent = false
	pulls_received = 0
	first_usec = 0
	if stage > codecs.size():
		_finish()
		return
	node = MorphspaceMesh.new()
	node.url = options["url"]
	node.space = options["space"]
	node.smoothing = 0.0
	node.params = {options["param"]: _values()[0]}
	if stage < codecs.size():
		node.codec = codecs[stage]
		node.rate = 60.0
	else:
		node.codec = "f32"
		node.pull_mode = true
	node.connect("frame_applied", self, "_on_applied")
	node.connect("frame_pulled", self, "_on_pulled")
	node.connect("error_received", self, "_on_error")
	node.connect("disconnected", self, "_on_disconnected")
	add_child(node)


func _process(_delta):
	if OS.get_ticks_msec() > deadline:
		_fail("timed out in stage %d after %d frames" % [stage, streamed])


func _on_applied(frame):
	var kind = "engine" if node.pull_mode else "stream"
	var now = OS.get_ticks_usec()
	if first_usec == 0:
		first_usec = now
		received_first = node.client.received_frames
	if options.get("record-vertices", "1") == "1":
		_record(kind, frame, node.mesh.surface_get_arrays(0)[Mesh.ARRAY_VERTEX], node.transform)
	else:
		_record(kind, frame, null, null)
	streamed += 1
	if kind == "engine":
		last_usec = now
		if streamed >= int(options["engine-frames"]):
			_finish_stage(kind)
		return
	var frames = int(options["frames"])
	if streamed == frames / 2:
		steer_seq = node.set_param(options["param"], _values()[1], true)
	if streamed == frames:  # the window of the frame rate figures
		last_usec = now
		received = node.client.received_frames
		superseded = node.client.skipped_frames
		server_dropped = frame["dropped"]
	if streamed >= frames and not pulls_sent:
		pulls_sent = true
		node.pause()
		for text in options["pulls"].split(","):
			node.pull({options["param"]: options["pull-value"].to_float()}, text.to_float())


func _on_pulled(frame):
	if node.pull_mode:
		return  # recorded when applied
	_record("pull", frame, frame["vertices"], null)
	pulls_received += 1
	if pulls_received == options["pulls"].split(",").size():
		_finish_stage("stream")


func _finish_stage(kind):
	var seconds = (last_usec - first_usec) / 1e6
	if kind == "engine":
		received = streamed
		received_first = 0
		superseded = node.client.skipped_frames
		server_dropped = 0
	var applied = min(streamed, int(options["frames"])) if kind == "stream" else streamed
	summary["codecs"]["%s-%s" % [kind, node.codec]] = {
		"frames": applied, "seconds": seconds, "frames_per_second": (applied - 1) / seconds if seconds > 0 else 0.0,
		"received": received, "received_in_window": received - received_first, "superseded": superseded,
		"server_dropped": server_dropped,
		"steer_seq": steer_seq,
		"engine_fps": Engine.get_frames_per_second()}
	call_deferred("_next_stage")


func _record(kind, frame, vertices, placed):
	var record = {"kind": kind, "codec": node.codec}
	for key in ["seq", "ack", "time", "phase", "mode", "requested", "realised", "weights", "root", "heading",
			"dropped", "pull_id", "decode_usec", "msgpack_usec"]:
		record[key] = frame.get(key)
	record["update_usec"] = frame.get("update_usec", -1)
	if vertices != null:
		record["vertices"] = var2bytes(vertices).subarray(8, 8 + 12 * vertices.size() - 1)
		record["n_vertices"] = vertices.size()
	if placed != null:
		var b = placed.basis
		record["basis"] = [b.x.x, b.y.x, b.z.x, b.x.y, b.y.y, b.z.y, b.x.z, b.y.z, b.z.z]  # rows
		record["origin"] = [placed.origin.x, placed.origin.y, placed.origin.z]
	if kind == "engine":
		record["pull_time"] = node.pull_time
	records.store_buffer(Msgpack.encode(record))


func _on_error(error):
	summary["errors"].append(error)
	_fail("server error %s: %s" % [error.get("code"), error.get("message")])


func _on_disconnected(reason, retry_in):
	summary["disconnects"].append(reason)


func _finish():
	records.close()
	var file = File.new()
	file.open(out_dir.plus_file("summary.msgpack"), File.WRITE)
	file.store_buffer(Msgpack.encode(summary))
	file.close()
	get_tree().quit(0)


func _fail(message):
	records.close()
	var file = File.new()
	file.open(out_dir.plus_file("error.txt"), File.WRITE)
	file.store_string(message + "\n")
	file.close()
	set_process(false)
	get_tree().quit(1)
