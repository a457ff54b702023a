# msgpack (https://msgpack.org) in GDScript: the subset of the format the morphspace stream
# uses, both ways. Godot 3 has no msgpack of its own.
#
#   const Msgpack = preload("res://addons/morphspace/msgpack.gd")
#   var bytes = Msgpack.encode({"type": "hello", "space": "locomotion"})
#   var result = Msgpack.decode(bytes)    # {"value": ..., "error": ""}
#
# decode: nil, bool, every int family (uint64 above 2^63 - 1 is an error: GDScript ints are
# int64), float32, float64, str (UTF-8), bin (PoolByteArray), array, map (Dictionary) and ext
# (an Ext with its type and data). Trailing bytes, truncated data and the unused byte 0xc1
# are errors. encode: null, bool, int (the smallest form), float (float64), String,
# PoolByteArray (bin), Array and the Pool arrays (array), Dictionary (map), Ext.
extends Reference

const MAX_DEPTH = 64


class Ext:
	var type = 0
	var data = PoolByteArray()

	func _init(ext_type, bytes):
		type = ext_type
		data = bytes


class Decoder:
	var buffer = StreamPeerBuffer.new()
	var size = 0
	var error = ""

	func _init(bytes):
		buffer.big_endian = true
		buffer.data_array = bytes
		size = bytes.size()

	func fail(message):
		if error == "":
			error = "%s at byte %d" % [message, buffer.get_position()]
		return null

	func has(n):
		return buffer.get_position() + n <= size

	func read(depth = 0):
		if error != "":
			return null
		if depth > MAX_DEPTH:
			return fail("nested deeper than %d" % MAX_DEPTH)
		if not has(1):
			return fail("truncated")
		var b = buffer.get_u8()
		if b <= 0x7f:
			return b
		if b >= 0xe0:
			return b - 256
		if (b & 0xf0) == 0x80:
			return read_map(b & 0x0f, depth)
		if (b & 0xf0) == 0x90:
			return read_array(b & 0x0f, depth)
		if (b & 0xe0) == 0xa0:
			return read_str(b & 0x1f)
		match b:
			0xc0:
				return null
			0xc2:
				return false
			0xc3:
				return true
			0xc4:
				return read_bin(read_length(1))
			0xc5:
				return read_bin(read_length(2))
			0xc6:
				return read_bin(read_length(4))
			0xc7:
				return read_ext(read_length(1))
			0xc8:
				return read_ext(read_length(2))
			0xc9:
				return read_ext(read_length(4))
			0xca:
				return buffer.get_float() if has(4) else fail("truncated float32")
			0xcb:
				return buffer.get_double() if has(8) else fail("truncated float64")
			0xcc:
				return buffer.get_u8() if has(1) else fail("truncated uint8")
			0xcd:
				return buffer.get_u16() if has(2) else fail("truncated uint16")
			0xce:
				return buffer.get_u32() if has(4) else fail("truncated uint32")
			0xcf:
				if not has(8):
					return fail("truncated uint64")
				var value = buffer.get_u64()
				return value if value >= 0 else fail("uint64 above 2^63 - 1")
			0xd0:
				return buffer.get_8() if has(1) else fail("truncated int8")
			0xd1:
				return buffer.get_16() if has(2) else fail("truncated int16")
			0xd2:
				return buffer.get_32() if has(4) else fail("truncated int32")
			0xd3:
				return buffer.get_64() if has(8) else fail("truncated int64")
			0xd4:
				return read_ext(1)
			0xd5:
				return read_ext(2)
			0xd6:
				return read_ext(4)
			0xd7:
				return read_ext(8)
			0xd8:
				return read_ext(16)
			0xd9:
				return read_str(read_length(1))
			0xda:
				return read_str(read_length(2))
			0xdb:
				return read_str(read_length(4))
			0xdc:
				return read_array(read_length(2), depth)
			0xdd:
				return read_array(read_length(4), depth)
			0xde:
				return read_map(read_length(2), depth)
			0xdf:
				return read_map(read_length(4), depth)
		return fail("invalid byte 0x%02x" % b)

	func read_length(width):
		if not has(width):
			fail("truncated length")
			return -1
		if width == 1:
			return buffer.get_u8()
		if width == 2:
			return buffer.get_u16()
		return buffer.get_u32()

	func read_bytes(n):
		if n < 0 or not has(n):
			fail("truncated data (%d bytes announced)" % n)
			return PoolByteArray()
		if n == 0:
			return PoolByteArray()
		return buffer.get_data(n)[1]

	func read_str(n):
		if n < 0 or not has(n):
			return fail("truncated string (%d bytes announced)" % n)
		if n == 0:
			return ""
		return buffer.get_utf8_string(n)

	func read_bin(n):
		var data = read_bytes(n)
		return data if error == "" else null

	func read_ext(n):
		if not has(1):
			return fail("truncated ext")
		var ext_type = buffer.get_8()
		var data = read_bytes(n)
		return Ext.new(ext_type, data) if error == "" else null

	func read_array(n, depth):
		# Every element takes at least one byte: a count beyond the data is an error before
		# anything is allocated.
		if n < 0 or not has(n):
			return fail("truncated array (%d elements announced)" % n)
		var out = []
		out.resize(n)
		for i in range(n):
			out[i] = read(depth + 1)
			if error != "":
				return null
		return out

	func read_map(n, depth):
		if n < 0 or not has(2 * n):
			return fail("truncated map (%d entries announced)" % n)
		var out = {}
		for i in range(n):
			var key = read(depth + 1)
			var value = read(depth + 1)
			if error != "":
				return null
			out[key] = value
		return out


static func decode(bytes):
	# {"value": the decoded value, "error": "" or what is wrong with the bytes}
	var decoder = Decoder.new(bytes)
	var value = decoder.read()
	if decoder.error == "" and decoder.buffer.get_position() != decoder.size:
		decoder.fail("%d trailing bytes" % (decoder.size - decoder.buffer.get_position()))
	if decoder.error != "":
		return {"value": null, "error": decoder.error}
	return {"value": value, "error": ""}


static func encode(value):
	# The msgpack bytes of value (see the top of this file for the types).
	var out = StreamPeerBuffer.new()
	out.big_endian = true
	_write(out, value, 0)
	return out.data_array


static func _write(out, value, depth):
	if depth > MAX_DEPTH:
		push_error("msgpack: nested deeper than %d" % MAX_DEPTH)
		out.put_u8(0xc0)
		return
	match typeof(value):
		TYPE_NIL:
			out.put_u8(0xc0)
		TYPE_BOOL:
			out.put_u8(0xc3 if value else 0xc2)
		TYPE_INT:
			_write_int(out, value)
		TYPE_REAL:
			out.put_u8(0xcb)
			out.put_double(value)
		TYPE_STRING:
			var bytes = value.to_utf8()
			_write_header(out, bytes.size(), 0xa0, 31, 0xd9, 0xda, 0xdb)
			out.put_data(bytes)
		TYPE_RAW_ARRAY:
			if value.size() < 256:
				out.put_u8(0xc4)
				out.put_u8(value.size())
			elif value.size() < 65536:
				out.put_u8(0xc5)
				out.put_u16(value.size())
			else:
				out.put_u8(0xc6)
				out.put_u32(value.size())
			out.put_data(value)
		TYPE_DICTIONARY:
			_write_header(out, value.size(), 0x80, 15, -1, 0xde, 0xdf)
			for key in value:
				_write(out, key, depth + 1)
				_write(out, value[key], depth + 1)
		TYPE_ARRAY, TYPE_INT_ARRAY, TYPE_REAL_ARRAY, TYPE_STRING_ARRAY:
			_write_header(out, value.size(), 0x90, 15, -1, 0xdc, 0xdd)
			for item in value:
				_write(out, item, depth + 1)
		TYPE_OBJECT:
			if value is Ext:
				out.put_u8(0xc7)
				out.put_u8(value.data.size())
				out.put_8(value.type)
				out.put_data(value.data)
			else:
				push_error("msgpack: cannot encode %s" % value)
				out.put_u8(0xc0)
		_:
			push_error("msgpack: cannot encode a value of type %d" % typeof(value))
			out.put_u8(0xc0)


static func _write_header(out, n, fix, fix_max, code8, code16, code32):
	if n <= fix_max:
		out.put_u8(fix | n)
	elif code8 >= 0 and n < 256:
		out.put_u8(code8)
		out.put_u8(n)
	elif n < 65536:
		out.put_u8(code16)
		out.put_u16(n)
	else:
		out.put_u8(code32)
		out.put_u32(n)


static func _write_int(out, value):
	if value >= 0:
		if value < 128:
			out.put_u8(value)
		elif value < 256:
			out.put_u8(0xcc)
			out.put_u8(value)
		elif value < 65536:
			out.put_u8(0xcd)
			out.put_u16(value)
		elif value < 4294967296:
			out.put_u8(0xce)
			out.put_u32(value)
		else:
			out.put_u8(0xcf)
			out.put_u64(value)
	else:
		if value >= -32:
			out.put_u8(value + 256)
		elif value >= -128:
			out.put_u8(0xd0)
			out.put_8(value)
		elif value >= -32768:
			out.put_u8(0xd1)
			out.put_16(value)
		elif value >= -2147483648:
			out.put_u8(0xd2)
			out.put_32(value)
		else:
			out.put_u8(0xd3)
			out.put_64(value)
