// Generated from server/protocol.py by `python -m server.protocol_docs --js`; do not edit.
// A test checks that this file matches the server's message definitions.
export const PROTOCOL_VERSION = 1;
export const CODECS = ["f32", "q16"];
export const MODES = ["linear", "hybrid", "nonlinear"];
export const CLIENT_MESSAGES = {
  "hello": [
    "type",
    "space",
    "graph",
    "node",
    "codec",
    "rate",
    "mode",
    "params",
    "smoothing",
    "window",
    "heatmap",
    "seq"
  ],
  "params": [
    "type",
    "params",
    "immediate",
    "seq"
  ],
  "mode": [
    "type",
    "mode",
    "seq"
  ],
  "rate": [
    "type",
    "rate",
    "seq"
  ],
  "pause": [
    "type",
    "seq"
  ],
  "resume": [
    "type",
    "seq"
  ],
  "seek": [
    "type",
    "phase",
    "seq"
  ],
  "reset": [
    "type",
    "seq"
  ],
  "heatmap": [
    "type",
    "on",
    "seq"
  ],
  "pull": [
    "type",
    "id",
    "params",
    "time",
    "phase",
    "mode"
  ],
  "action": [
    "type",
    "node",
    "params",
    "budget",
    "seq"
  ],
  "ack": [
    "type",
    "frame"
  ]
};
export const SERVER_MESSAGES = {
  "topology": [
    "type",
    "protocol",
    "space",
    "n_vertices",
    "n_faces",
    "faces",
    "codec",
    "bounds_min",
    "bounds_max",
    "quantisation_error",
    "parameters",
    "sources",
    "durations",
    "cyclic",
    "mode",
    "modes",
    "rate",
    "model_size",
    "limits",
    "graph",
    "nodes",
    "edges"
  ],
  "frame": [
    "type",
    "seq",
    "ack",
    "time",
    "phase",
    "mode",
    "requested",
    "realised",
    "clamped",
    "weights",
    "root",
    "heading",
    "vertices",
    "dropped",
    "finished",
    "sent_at",
    "pull_id",
    "error_um",
    "error_max",
    "error_seq",
    "node",
    "target",
    "progress"
  ],
  "notice": [
    "type",
    "code",
    "message",
    "seq"
  ],
  "error": [
    "type",
    "code",
    "message",
    "ref",
    "seq"
  ]
};
export const ERROR_CODES = ["malformed", "unknown_type", "invalid_field", "unknown_space", "unknown_graph", "unknown_node", "unsupported", "not_playable", "not_ready", "too_large", "rate_limited", "invalid_params", "server_busy", "internal"];
