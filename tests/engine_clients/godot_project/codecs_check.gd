# The add-on's msgpack and codecs on data made by tests/engine_clients/test_godot.py
# (run as the scene res://codecs_check.tscn; user arguments --in=FILE --out=FILE).
#
# Input (msgpack): {"values": any value, "malformed": [bin...], "q16": [{n, data, lo, hi}...],
# "faces": {n, data}}. Output (msgpack, written with the add-on's encoder): {"echo": values
# decoded and encoded again, "errors": the decoder's error for each malformed input, "q16":
# [float32 bytes of decode_q16], "q16_loop": [float32 bytes of decode_q16_loop], "faces": the
# indices of face_indices}.
extends Node

const Msgpack = preload("res://addons/morphspace/msgpack.gd")
const Codecs = preload("res://addons/morphspace/codecs.gd")


func _ready():
	var options = {}
	for arg in OS.get_cmdline_args():
		if arg.begins_with("--") and "=" in arg:
			var cut = arg.find("=")
			options[arg.substr(2, cut - 2)] = arg.substr(cut + 1)
	var file = File.new()
	file.open(options["in"], File.READ)
	var decoded = Msgpack.decode(file.get_buffer(file.get_len()))
	file.close()
	if decoded["error"] != "":
		push_error(decoded["error"])
		get_tree().quit(1)
		return
	var input = decoded["value"]
	var output = {"echo": input["values"], "errors": [], "q16": [], "q16_loop": []}
	for bytes in input["malformed"]:
		output["errors"].append(Msgpack.decode(bytes)["error"])
	for case in input["q16"]:
		var fast = Codecs.decode_vertices(case["data"], "q16", case["n"], case["lo"], case["hi"])
		var plain = Codecs.decode_q16_loop(case["data"], case["n"], case["lo"], case["hi"])
		output["q16"].append(var2bytes(fast).subarray(8, 8 + 12 * case["n"] - 1))
		output["q16_loop"].append(var2bytes(plain).subarray(8, 8 + 12 * case["n"] - 1))
	output["faces"] = Array(Codecs.face_indices(input["faces"]["data"], input["faces"]["n"]))
	file.open(options["out"], File.WRITE)
	file.store_buffer(Msgpack.encode(output))
	file.close()
	get_tree().quit(0)
