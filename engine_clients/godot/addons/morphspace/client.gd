# One connection to a morphspace server's /v1/stream (docs/protocol.md), without a scene:
# a Reference that a node polls every frame (MorphspaceMesh does).
#
#   var client = preload("res://addons/morphspace/client.gd").new()
#   client.url = "ws://127.0.0.1:8000/v1/stream"
#   client.space = "locomotion"
#   client.connect("frame_received", self, "_on_frame")
#   client.start()
#   ...  client.poll(delta) in _process
#
# Sends hello (space, or graph and node; codec, rate, mode, smoothing, window, params), then
# params / mode / rate / pause / resume / seek / reset / heatmap / action with a sequence number
# each, and pull with an id. On a motion graph every streamed frame names the node shown, the
# transition's target and its progress: graph_state (graph_state.gd) keeps them with the
# topology's nodes and edges, and the client emits node_changed when the node shown changes.
# Decodes every message itself (msgpack.gd) and the vertices (codecs.gd). Streamed frames are
# latest-wins here too: of the frames that arrived since the last poll only the newest is
# decoded and emitted (the others are counted in skipped_frames); every pulled frame is emitted.
# When the connection drops (or never opens) it reconnects after a delay that doubles from
# reconnect_min to reconnect_max (reset by the next topology), sending hello again with the
# parameters last requested.
extends Reference

const Msgpack = preload("res://addons/morphspace/msgpack.gd")
const Codecs = preload("res://addons/morphspace/codecs.gd")
const GraphState = preload("res://addons/morphspace/graph_state.gd")

signal connected()
signal disconnected(reason, retry_in)  # retry_in: seconds until the next attempt, -1 for none
signal topology_received(topology)     # the topology map, plus "indices" (PoolIntArray, clockwise)
signal frame_received(frame)           # a streamed frame (see _frame for its fields)
signal pull_received(frame)            # a frame answering pull(); frame.pull_id is its id
signal error_received(error)           # {code, message, ref, seq}: a message was not acted on
signal notice_received(notice)         # {code, message, seq}
signal node_changed(node, previous)    # graphs: the emitted frames' node changed (previous "" at first)

enum State { IDLE, CONNECTING, OPEN, WAITING }

# The hello.
var url = "ws://127.0.0.1:8000/v1/stream"
var space = ""
var graph = ""                # or a motion graph's name (then space is not sent)
var node = ""                 # with graph: the start node ("": the graph's first cyclic node)
var codec = "f32"
var rate = 60.0
var mode = "hybrid"
var smoothing = 0.25
var window = 0
var heatmap = false
var params = {}               # the parameters last requested (sent again on reconnecting)
# Reconnecting.
var auto_reconnect = true
var reconnect_min = 0.5       # seconds
var reconnect_max = 10.0
var connect_timeout = 10.0    # seconds for the WebSocket to open
var silence_timeout = 5.0     # seconds without a message while frames are due: the connection is
                              # taken as lost (a server that stopped without closing it); 0: off
var input_buffer_kb = 8192    # WebSocket receive buffer (a 10k-vertex f32 frame is 120 KB)

var state = State.IDLE
var topology = null
var parameter_names = []
var last_seq = 0              # the seq of the last control message (frames with ack >= it reflect it)
var skipped_frames = 0        # streamed frames superseded before they were decoded
var received_frames = 0       # streamed frames that arrived (decoded or superseded)
var attempts = 0              # connection attempts since the last topology
var graph_state = GraphState.new()  # motion graphs: nodes, edges, node / target / progress

var _socket = null
var _next_seq = 1
var _next_pull_id = 1
var _pending_pulls = {}
var _wait = 0.0
var _delay = 0.0
var _close_reason = ""
var _silence = 0.0            # seconds since the last message arrived
var _paused = false           # the stream is paused (pause() until resume() or the next hello)


func start():
	# Connect (again) now.
	_delay = reconnect_min
	_open()


func stop():
	# Close and stay closed.
	auto_reconnect = false
	if _socket != null:
		_socket.disconnect_from_host(1000, "bye")
	_drop_socket()
	state = State.IDLE


func is_open():
	return state == State.OPEN and topology != null


func poll(delta):
	# Call every frame: drives the socket, emits what arrived, reconnects when due.
	if state == State.WAITING:
		_wait -= delta
		if _wait <= 0.0:
			_open()
		return
	var socket = _socket  # held here: a signal emitted inside poll() may drop _socket
	if socket == null:
		return
	socket.poll()
	if state == State.CONNECTING:
		_wait -= delta
		if _wait <= 0.0 and _socket == socket:
			_lost("no connection within %s s" % connect_timeout)
		return
	if state == State.OPEN and _socket == socket:
		if _read_packets(socket) > 0:
			_silence = 0.0
		else:
			_silence += delta  # (after reading: a long hitch in the game finds its frames waiting)
		var due = topology != null and not _paused and rate > 0.0
		if due and silence_timeout > 0.0 and _silence > max(silence_timeout, 3.0 / rate) and _socket == socket:
			_lost("no message from the server for %.1f s" % _silence)


# ------------------------------------------------------------------ requests

func hello(new_space = null):
	# (Re)start streaming (the space, or the graph when graph is set): a new topology follows and
	# frame numbers restart at 1.
	if new_space != null:
		space = new_space
		graph = ""
	topology = null
	_paused = false  # (a hello starts the stream afresh, unpaused)
	_silence = 0.0
	graph_state.clear_frame()
	var message = {"type": "hello", "codec": codec, "rate": float(rate), "mode": mode,
			"smoothing": float(smoothing), "window": int(window), "heatmap": heatmap}
	if graph != "":
		message["graph"] = graph
		if node != "":
			message["node"] = node
	else:
		message["space"] = space
	if not params.empty():
		message["params"] = params.duplicate()
	return _control(message)


func hello_graph(new_graph, start_node = ""):
	# (Re)start streaming the motion graph new_graph from start_node ("": its first cyclic node).
	# params are the start node's: those of another graph's nodes are dropped.
	if new_graph != graph:
		params = {}
	graph = new_graph
	node = start_node
	return hello()


func set_params(values, immediate = false):
	# Request parameters (only the named ones change); returns the message's seq. On a graph they
	# are the shown node's (during a blend: its target's).
	var shown = graph_state.steered_node()
	if graph == "" or shown == graph_state.start_node:
		for name in values:
			params[name] = values[name]
	if graph != "":
		graph_state.remember(shown, values)
	return _control({"type": "params", "params": values.duplicate(), "immediate": immediate})


func set_mode(new_mode):
	mode = new_mode
	return _control({"type": "mode", "mode": new_mode})


func set_rate(new_rate):
	rate = new_rate
	_silence = 0.0
	return _control({"type": "rate", "rate": float(new_rate)})


func pause():
	_paused = true
	return _control({"type": "pause"})


func resume():
	_paused = false
	_silence = 0.0
	return _control({"type": "resume"})


func seek(phase):
	return _control({"type": "seek", "phase": float(phase)})


func reset():
	return _control({"type": "reset"})


func set_heatmap(on):
	heatmap = on
	return _control({"type": "heatmap", "on": on})


func action(node_name, action_params = {}, budget = null):
	# On a graph: go to node_name at these parameters (missing ones: what the node was last asked
	# for), within budget seconds if given. Returns the message's seq; the server answers with a
	# notice (planned or queued, notice_received) and frames with ack >= seq follow the action.
	var message = {"type": "action", "node": node_name}
	if not action_params.empty():
		message["params"] = action_params.duplicate()
	if budget != null:
		message["budget"] = float(budget)
	graph_state.remember(node_name, action_params)
	if node_name == graph_state.start_node:
		for name in action_params:
			params[name] = action_params[name]
	return _control(message)


func pull(pull_params = null, time = null, phase = null, pull_mode = null):
	# Ask for the frame at these parameters (missing ones: the stream's request) and time (s)
	# or phase; returns the pull id (the answering frame's pull_id), or -1 when not connected.
	if not is_open():
		return -1
	var message = {"type": "pull", "id": _next_pull_id}
	if pull_params != null:
		message["params"] = pull_params.duplicate()
	if time != null:
		message["time"] = float(time)
	else:
		message["phase"] = float(phase if phase != null else 0.0)
	if pull_mode != null:
		message["mode"] = pull_mode
	_next_pull_id += 1
	_pending_pulls[message["id"]] = OS.get_ticks_usec()
	_send(message)
	return message["id"]


func pending_pulls():
	return _pending_pulls.size()


func _control(message):
	message["seq"] = _next_seq
	_next_seq += 1
	last_seq = message["seq"]
	if state == State.OPEN:
		_send(message)
	return message["seq"]


func _send(message):
	var peer = _socket.get_peer(1)
	peer.put_packet(Msgpack.encode(message))


# ------------------------------------------------------------------ connection

func _open():
	_drop_socket()
	attempts += 1
	_socket = WebSocketClient.new()
	_socket.set_buffers(input_buffer_kb, 1024, 256, 1024)
	_socket.connect("connection_established", self, "_on_open")
	_socket.connect("connection_error", self, "_on_connection_error")
	_socket.connect("connection_closed", self, "_on_closed")
	_socket.connect("server_close_request", self, "_on_close_request")
	_close_reason = ""
	var err = _socket.connect_to_url(url)
	if err != OK:
		_lost("cannot connect to %s (error %d)" % [url, err])
		return
	state = State.CONNECTING
	_wait = connect_timeout


func _drop_socket():
	if _socket != null:
		for name in ["connection_established", "connection_error", "connection_closed", "server_close_request"]:
			var method = {"connection_established": "_on_open", "connection_error": "_on_connection_error",
					"connection_closed": "_on_closed", "server_close_request": "_on_close_request"}[name]
			if _socket.is_connected(name, self, method):
				_socket.disconnect(name, self, method)
	_socket = null
	topology = null
	_pending_pulls.clear()


func _on_open(_protocol):
	_socket.get_peer(1).set_write_mode(WebSocketPeer.WRITE_MODE_BINARY)
	_silence = 0.0
	state = State.OPEN
	emit_signal("connected")
	hello()


func _on_connection_error():
	_lost("connection to %s failed" % url)


func _on_close_request(code, reason):
	_close_reason = "closed by the server (%d%s)" % [code, ": " + reason if reason != "" else ""]


func _on_closed(_was_clean):
	_lost(_close_reason if _close_reason != "" else "connection closed")


func _lost(reason):
	_drop_socket()
	var retry_in = -1.0
	if auto_reconnect:
		retry_in = _delay
		_wait = _delay
		_delay = min(_delay * 2.0, reconnect_max)
		state = State.WAITING
	else:
		state = State.IDLE
	emit_signal("disconnected", reason, retry_in)


# ------------------------------------------------------------------ receiving

func _read_packets(socket):
	# Reads what arrived; returns how many messages that was.
	var newest = null
	var count = 0
	var peer = socket.get_peer(1)
	while _socket == socket and peer.get_available_packet_count() > 0:
		var packet = peer.get_packet()
		count += 1
		if peer.was_string_packet():
			continue  # the server only sends binary messages
		var started = OS.get_ticks_usec()
		var result = Msgpack.decode(packet)
		if result["error"] != "" or typeof(result["value"]) != TYPE_DICTIONARY:
			emit_signal("error_received", {"code": "malformed", "message": "a server message is not a msgpack map: "
					+ result["error"], "ref": null, "seq": null})
			continue
		var message = result["value"]
		match message.get("type"):
			"frame":
				message["msgpack_usec"] = OS.get_ticks_usec() - started
				if message.get("pull_id") != null:
					_emit_frame(message, "pull_received")
				else:
					received_frames += 1
					if newest != null:
						skipped_frames += 1
					newest = message
			"topology":
				newest = null  # frames of an earlier hello
				_on_topology(message)
			"error":
				if message.get("ref") == "pull":
					_pending_pulls.erase(message.get("seq"))
				emit_signal("error_received", message)
			"notice":
				emit_signal("notice_received", message)
	if newest != null and topology != null:
		_emit_frame(newest, "frame_received")
		if window > 0 and state == State.OPEN:
			_send({"type": "ack", "frame": newest["seq"]})
	return count


func _on_topology(message):
	var indices = Codecs.face_indices(message["faces"], message["n_faces"])
	if indices == null:
		emit_signal("error_received", {"code": "malformed", "message": "topology: faces hold %d bytes, not %d triangles"
				% [message["faces"].size(), message["n_faces"]], "ref": "topology", "seq": null})
		return
	message["indices"] = indices
	topology = message
	parameter_names = []
	for p in message["parameters"]:
		parameter_names.append(p["name"])
		if not params.has(p["name"]):
			params[p["name"]] = p["value"]
	codec = message["codec"]
	graph_state.read_topology(message)
	_delay = reconnect_min
	attempts = 0
	emit_signal("topology_received", message)


func _emit_frame(frame, signal_name):
	# Adds to the decoded map: vertices (PoolVector3Array, root-local), transform (the root
	# transform: heading about +Y, then root), requested_params / realised_params (name -> value)
	# and decode_usec (msgpack + vertex decoding, microseconds).
	var started = OS.get_ticks_usec()
	var t = topology
	var vertices = Codecs.decode_vertices(frame["vertices"], t["codec"], t["n_vertices"], t["bounds_min"], t["bounds_max"])
	if vertices == null:
		emit_signal("error_received", {"code": "malformed", "message": "frame %d: %d vertex bytes do not hold %d %s vertices"
				% [frame["seq"], frame["vertices"].size(), t["n_vertices"], t["codec"]], "ref": "frame", "seq": null})
		return
	frame["vertices"] = vertices
	var root = frame["root"]
	frame["transform"] = Transform(Basis(Vector3.UP, frame["heading"]), Vector3(root[0], root[1], root[2]))
	var names = parameter_names
	if frame.get("node") != null:
		names = graph_state.parameter_names(frame["node"], parameter_names)
	frame["requested_params"] = _named(frame["requested"], names)
	frame["realised_params"] = _named(frame["realised"], names)
	frame["decode_usec"] = frame["msgpack_usec"] + OS.get_ticks_usec() - started
	if frame.get("pull_id") != null:
		_pending_pulls.erase(frame["pull_id"])
	elif frame.get("node") != null:
		var previous = graph_state.follow(frame)
		if previous != null:
			emit_signal("node_changed", frame["node"], previous)
	emit_signal(signal_name, frame)


func _named(values, names):
	var out = {}
	for i in range(min(values.size(), names.size())):
		out[names[i]] = values[i]
	return out
