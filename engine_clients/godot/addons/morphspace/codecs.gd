# The stream's vertex codecs (docs/protocol.md, "Codecs"), bytes -> PoolVector3Array.
#
#   f32: n x 3 little-endian float32. Godot's own binary serialisation of a PoolVector3Array
#        (Variant type, count, then the float32 triples, all little-endian: the "Binary
#        serialization API" of Godot 3) is exactly these bytes behind an 8-byte header, so
#        bytes2var turns a frame into a PoolVector3Array in one native copy.
#   q16: n x 3 little-endian uint16 over the topology's box:
#        v = bounds_min + q * (bounds_max - bounds_min) / 65535 per axis.
#        Native code does it (decode_q16): an Image of RG8 pixels (one per uint16) converted to
#        RGBA8 appends the bytes 0x00, 0xFF to every value, which makes the float32 with bits
#        0xFF00_qqqq, exactly -(1 + q / 2^23) * 2^127; one Transform (scale by -2^-104, move by
#        -2^23: exact in float32) gives q, a second (scale by the step, move by bounds_min) the
#        position, rounded as the server's own decoder rounds (float32 q * step + bounds_min).
#        decode_q16_loop is the plain StreamPeerBuffer loop, used beyond the Image size limit.
#
# Faces: n_faces x 3 little-endian uint32, counter-clockwise; Godot 3 draws clockwise
# triangles as front faces, so face_indices swaps the last two indices of every triangle.
extends Reference


static func _with_header(variant_type, count, data):
	var header = StreamPeerBuffer.new()  # little-endian, like Godot's marshalling
	header.put_32(variant_type)
	header.put_32(count)
	var bytes = header.data_array
	bytes.append_array(data)
	return bytes2var(bytes)


static func decode_vertices(data, codec, n_vertices, bounds_min, bounds_max):
	# A PoolVector3Array of the frame's root-local vertices, or null when the bytes do not
	# hold n_vertices of the codec.
	if codec == "f32":
		if data.size() != 12 * n_vertices:
			return null
		return _with_header(TYPE_VECTOR3_ARRAY, n_vertices, data)
	if codec == "q16":
		if data.size() != 6 * n_vertices:
			return null
		return decode_q16(data, n_vertices, bounds_min, bounds_max)
	return null


const _IMAGE_WIDTH = 12288        # pixels per Image row (a multiple of 3, under Image's 16384)
const _IMAGE_MAX_HEIGHT = 16384


static func decode_q16(data, n_vertices, bounds_min, bounds_max):
	var pixels = 3 * n_vertices
	var width = min(pixels, _IMAGE_WIDTH)
	var height = (pixels + width - 1) / width
	if n_vertices == 0 or height > _IMAGE_MAX_HEIGHT:
		return decode_q16_loop(data, n_vertices, bounds_min, bounds_max)
	var bytes = data
	if width * height != pixels:
		bytes = PoolByteArray(data)
		bytes.resize(2 * width * height)
	var image = Image.new()
	image.create_from_data(width, height, false, Image.FORMAT_RG8, bytes)
	image.convert(Image.FORMAT_RGBA8)
	var floats = image.get_data()
	if floats.size() != 12 * n_vertices:
		floats = floats.subarray(0, 12 * n_vertices - 1)
	var scale = -pow(2.0, -104.0)
	var to_q = Transform(Basis(Vector3(scale, 0, 0), Vector3(0, scale, 0), Vector3(0, 0, scale)),
			Vector3(-8388608.0, -8388608.0, -8388608.0))
	var low = Vector3(bounds_min[0], bounds_min[1], bounds_min[2])
	var step = (Vector3(bounds_max[0], bounds_max[1], bounds_max[2]) - low) / 65535.0
	var to_metres = Transform(Basis(Vector3(step.x, 0, 0), Vector3(0, step.y, 0), Vector3(0, 0, step.z)), low)
	return to_metres.xform(to_q.xform(_with_header(TYPE_VECTOR3_ARRAY, n_vertices, floats)))


static func decode_q16_loop(data, n_vertices, bounds_min, bounds_max):
	var low = Vector3(bounds_min[0], bounds_min[1], bounds_min[2])
	var high = Vector3(bounds_max[0], bounds_max[1], bounds_max[2])
	var step = (high - low) / 65535.0
	var reader = StreamPeerBuffer.new()
	reader.data_array = data
	var out = PoolVector3Array()
	out.resize(n_vertices)
	for i in range(n_vertices):
		out[i] = low + Vector3(reader.get_u16(), reader.get_u16(), reader.get_u16()) * step
	return out


static func face_indices(data, n_faces):
	# A PoolIntArray of 3 * n_faces indices in Godot's clockwise order, or null when the
	# bytes do not hold n_faces triangles.
	if data.size() != 12 * n_faces:
		return null
	var indices = _with_header(TYPE_INT_ARRAY, 3 * n_faces, data)
	for f in range(n_faces):
		var second = indices[3 * f + 1]
		indices[3 * f + 1] = indices[3 * f + 2]
		indices[3 * f + 2] = second
	return indices
