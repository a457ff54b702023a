// Client messages built from the generated protocol tables (protocol.js), so the page can only
// send what server/protocol.py defines; server messages are checked against the same tables.
import { encode, decode } from "@msgpack/msgpack";
import { CLIENT_MESSAGES, SERVER_MESSAGES } from "../protocol.js";

export class MessageError extends Error {}

/** msgpack bytes of the client message `type` with `fields` (undefined fields are left out). */
export function clientMessage(type, fields = {}) {
  const names = CLIENT_MESSAGES[type];
  if (!names) throw new MessageError(`no client message of type ${JSON.stringify(type)}`);
  const body = { type };
  for (const [name, value] of Object.entries(fields)) {
    if (!names.includes(name)) {
      throw new MessageError(`${type} has no field ${JSON.stringify(name)} (fields: ${names.join(", ")})`);
    }
    if (value !== undefined && value !== null) body[name] = value;
  }
  return encode(body);
}

/** A server message object from WebSocket bytes; throws MessageError on anything unknown. */
export function serverMessage(bytes) {
  const raw = decode(new Uint8Array(bytes));
  if (raw === null || typeof raw !== "object" || typeof raw.type !== "string") {
    throw new MessageError("server message is not a map with a string type");
  }
  const names = SERVER_MESSAGES[raw.type];
  if (!names) throw new MessageError(`unknown server message type ${JSON.stringify(raw.type)}`);
  return raw;
}

/** The field names of a server message type (for checks and the status overlay). */
export function serverFields(type) {
  return SERVER_MESSAGES[type] || [];
}
