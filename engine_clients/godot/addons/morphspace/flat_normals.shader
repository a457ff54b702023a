// MorphspaceMesh's default material: the stream sends positions only, so the normal of each
// pixel is taken from the screen-space derivatives of its position (faceted shading, no
// per-frame normal computation on the CPU).
shader_type spatial;

uniform vec4 albedo : hint_color = vec4(0.78, 0.72, 0.66, 1.0);
uniform float roughness : hint_range(0, 1) = 0.7;

void fragment() {
	NORMAL = normalize(cross(dFdx(VERTEX), dFdy(VERTEX)));
	ALBEDO = albedo.rgb;
	ROUGHNESS = roughness;
}
