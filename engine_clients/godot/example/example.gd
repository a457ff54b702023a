# The example scene: a MorphspaceMesh streaming the demo locomotion space from a local
# `morphspace serve`, steered with the arrow keys (up / down: speed, left / right: turn rate),
# with a camera that follows the character along its path.
extends Spatial

onready var character = $Character
onready var camera = $Camera
onready var status = $Status

var speed = 1.3
var turn_rate = 0.0


func _ready():
	character.connect("topology_received", self, "_on_topology")
	character.connect("frame_applied", self, "_on_frame")
	character.connect("error_received", self, "_on_error")
	character.connect("disconnected", self, "_on_disconnected")


func _process(delta):
	var speed_step = (Input.get_action_strength("ui_up") - Input.get_action_strength("ui_down")) * delta
	var turn_step = (Input.get_action_strength("ui_left") - Input.get_action_strength("ui_right")) * 60.0 * delta
	if speed_step != 0.0 or turn_step != 0.0:
		speed = clamp(speed + speed_step, 0.0, 4.0)
		turn_rate = clamp(turn_rate + turn_step, -90.0, 90.0)
		character.set_params({"speed": speed, "turn_rate": turn_rate})
	var target = character.global_transform.origin + Vector3(0, 1.0, 0)
	camera.look_at_from_position(target + Vector3(0, 0.8, 4.0), target, Vector3.UP)


func _on_topology(topology):
	status.text = "%s: %d vertices, parameters %s" % [topology["space"], topology["n_vertices"], character.client.parameter_names]


func _on_frame(frame):
	status.text = "speed %.2f m/s, turn %.0f deg/s, decode %d us, mesh %d us, dropped %d" % [
		frame["realised_params"].get("speed", 0.0), frame["realised_params"].get("turn_rate", 0.0),
		frame["decode_usec"], frame["update_usec"], frame["dropped"]]


func _on_error(error):
	status.text = "error %s: %s" % [error["code"], error["message"]]


func _on_disconnected(reason, retry_in):
	status.text = "%s; trying again in %.1f s" % [reason, retry_in]
