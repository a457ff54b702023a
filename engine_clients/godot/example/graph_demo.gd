# The example's motion-graph scene: a MorphspaceMesh streaming the demo motion graph from a local
# `morphspace serve`. Space jumps (the graph's jump action), R reaches, the arrow keys steer the
# walk (up / down: speed, left / right: turn rate, sent only while the node shown has them); the
# camera follows the character across transitions. Run it with
#     godot3 --path engine_clients/godot res://example/graph_demo.tscn
# Options after `--` (the headless test uses them): --url=ws://HOST:PORT/v1/stream, --graph=NAME,
# --press=T:KEY,T:KEY (press Space or R at T seconds after the first frame, as a player would),
# --quit-after=S (seconds after the first frame; with no frame by S seconds after the start, the
# scene quits with status 1 and a "no_frames" error) and --out=FILE (a JSON summary written at the
# end). A malformed --press (not T:space or T:r) quits at once with status 1 and a "bad_option" error.
extends Spatial

onready var character = $Character
onready var camera = $Camera
onready var status = $Status

var speed = 1.3
var turn_rate = 0.0
var jump_height = 0.45
var reach_height = 1.6
var options = {}
var presses = []          # [[seconds, scancode]] still to press
var started = -1.0        # seconds (engine time) of the first frame applied
var clock = 0.0
var visited = []          # the nodes the applied frames showed, in order
var notices = []
var errors = []
var disconnects = []      # the reasons the connection dropped (no server, the server closed it)


func _ready():
	for arg in OS.get_cmdline_args():
		if arg.begins_with("--") and "=" in arg:
			var cut = arg.find("=")
			options[arg.substr(2, cut - 2)] = arg.substr(cut + 1)
	if options.has("url"):
		character.url = options["url"]
	if options.has("graph"):
		character.graph = options["graph"]
	for entry in options.get("press", "").split(",", false):
		var parts = entry.split(":")
		if parts.size() != 2 or not parts[0].is_valid_float() or not parts[1] in ["space", "r"]:
			errors.append({"code": "bad_option", "message": "--press=%s: each press is T:space or T:r (T seconds after the first frame), not '%s'" % [options["press"], entry]})
			call_deferred("_finish", 1)
			return
		presses.append([parts[0].to_float(), KEY_SPACE if parts[1] == "space" else KEY_R])
	if options.has("quit-after") and not options["quit-after"].is_valid_float():
		errors.append({"code": "bad_option", "message": "--quit-after=%s: not a number of seconds" % options["quit-after"]})
		call_deferred("_finish", 1)
		return
	character.connect("node_changed", self, "_on_node_changed")
	character.connect("disconnected", self, "_on_disconnected")
	character.connect("frame_applied", self, "_on_frame")
	character.connect("notice_received", self, "_on_notice")
	character.connect("error_received", self, "_on_error")
	if options.has("url") or options.has("graph"):
		character.start()  # again, with the options (autostart connected with the scene's values)


func _unhandled_input(event):
	if not (event is InputEventKey and event.pressed and not event.echo):
		return
	if event.scancode == KEY_SPACE:
		character.action("jump", {"jump_height": jump_height})
	elif event.scancode == KEY_R:
		character.action("reach", {"reach_height": reach_height})


func _process(delta):
	clock += delta
	var speed_step = (Input.get_action_strength("ui_up") - Input.get_action_strength("ui_down")) * delta
	var turn_step = (Input.get_action_strength("ui_left") - Input.get_action_strength("ui_right")) * 60.0 * delta
	if speed_step != 0.0 or turn_step != 0.0:
		speed = clamp(speed + speed_step, 0.0, 4.0)
		turn_rate = clamp(turn_rate + turn_step, -90.0, 90.0)
		var wanted = {}
		for p in character.parameters():  # the node shown's: a stand or a jump has no speed
			if p["name"] == "speed":
				wanted["speed"] = speed
			elif p["name"] == "turn_rate":
				wanted["turn_rate"] = turn_rate
		if not wanted.empty():
			character.set_params(wanted)
	var target = character.global_transform.origin + Vector3(0, 1.0, 0)
	camera.look_at_from_position(target + Vector3(0, 0.8, 4.0), target, Vector3.UP)
	if started < 0.0:
		if options.has("quit-after") and clock >= options["quit-after"].to_float():
			errors.append({"code": "no_frames", "message": "no frame in %s s from %s (graph %s): %s" % [
				options["quit-after"], character.url, character.graph,
				disconnects.back() if not disconnects.empty() else "connected, nothing streamed"]})
			_finish(1)
		return
	while not presses.empty() and clock - started >= presses[0][0]:
		var key = InputEventKey.new()
		key.scancode = presses.pop_front()[1]
		key.pressed = true
		Input.parse_input_event(key)  # through the engine's input, as a key press
	if options.has("quit-after") and clock - started >= options["quit-after"].to_float():
		_finish()


func _on_frame(frame):
	if started < 0.0:
		started = clock
	var where = character.current_node
	if character.progress != null:
		where = "%s -> %s %d%%" % [character.current_node, character.target_node, int(100 * character.progress)]
	elif character.target_node != null:
		where = "%s (then %s)" % [character.current_node, character.target_node]
	status.text = "%s; Space: jump, R: reach, arrows: walk; decode %d us, mesh %d us" % [
		where, frame["decode_usec"], frame["update_usec"]]


func _on_node_changed(node, _previous):
	visited.append(node)


func _on_notice(notice):
	notices.append(notice)


func _on_disconnected(reason, _retry_in):
	disconnects.append(reason)


func _on_error(error):
	errors.append(error)
	status.text = "error %s: %s" % [error["code"], error["message"]]


func _finish(status = 0):
	set_process(false)
	character.stop()
	if options.has("out"):
		var file = File.new()
		file.open(options["out"], File.WRITE)
		file.store_string(to_json({"visited": visited, "notices": notices, "errors": errors,
				"disconnects": disconnects, "frames": character.frames_applied, "root": [character.transform.origin.x,
				character.transform.origin.y, character.transform.origin.z]}))
		file.close()
	get_tree().quit(status)
