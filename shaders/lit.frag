#version 450 core
// Protocol 2 of PROTOCOL.md, the GLSL twin of geoscaler/render/lit.py: every map of a glTF
// metallic-roughness material sampled as mesh.frag samples the base colour (trilinear, the
// level of detail of each map's own size), the normal map read in the sample's tangent frame,
// and the BRDF of the glTF specification's Appendix B under two camera-relative directional
// lights and a uniform ambient. Base colour and emissive are GL_SRGB8_ALPHA8 (decoded by the
// hardware); the other maps hold their linear values in float textures.

const int BASE_COLOR = 0, METALLIC_ROUGHNESS = 1, NORMAL = 2, OCCLUSION = 3, EMISSIVE = 4;
const float PI = 3.14159265358979;

uniform sampler2D maps[5];
uniform bool has_map[5];
uniform float max_level[5];  // mip levels - 1
uniform vec3 base_color_factor;  // linear RGB
uniform float metallic_factor;
uniform float roughness_factor;
uniform float normal_scale;
uniform float occlusion_strength;
uniform vec3 emissive;  // factor x strength
uniform vec3 eye;
uniform vec3 light_direction[2];  // unit, towards the light
uniform float light_irradiance[2];
uniform float ambient;
uniform float min_roughness;

in vec3 v_position;
in vec3 v_normal;
in vec4 v_tangent;
in vec2 v_uv;
noperspective in vec3 v_uvw;

layout(location = 0) out vec4 colour;  // linear RGB radiance in [0, 1], alpha 1 marks coverage

float level_of_detail(vec3 uvw, vec2 size) {
    vec3 ddx = dFdxFine(uvw);
    vec3 ddy = dFdyFine(uvw);
    vec2 uv = uvw.xy / uvw.z;
    vec2 dx = (ddx.xy - uv * ddx.z) / uvw.z * size;
    vec2 dy = (ddy.xy - uv * ddy.z) / uvw.z * size;
    float frobenius = dot(dx, dx) + dot(dy, dy);
    float det = dx.x * dy.y - dy.x * dx.y;
    float gap = sqrt(max(frobenius * frobenius - 4.0 * det * det, 1e-20));
    return 0.5 * log2(max(0.5 * (frobenius + gap), 1e-30));
}

vec3 fetch(sampler2D map, float levels) {
    vec2 size = vec2(textureSize(map, 0));
    float lod = clamp(level_of_detail(v_uvw, size), 0.0, levels);
    return textureLod(map, v_uv, lod).rgb;
}

vec3 shading_normal(vec3 view) {
    vec3 n = normalize(v_normal);
    float facing = dot(n, view) < 0.0 ? -1.0 : 1.0;  // the back of the surface: frame turned round
    if (!has_map[NORMAL]) return facing * n;
    vec3 t = v_tangent.xyz - n * dot(n, v_tangent.xyz);
    t = t / max(length(t), 1e-12);
    vec3 b = (v_tangent.w < 0.0 ? -1.0 : 1.0) * cross(n, t);
    vec3 m = 2.0 * fetch(maps[NORMAL], max_level[NORMAL]) - 1.0;
    return facing * normalize(m.x * normal_scale * t + m.y * normal_scale * b + m.z * n);
}

void main() {
    vec3 view = normalize(eye - v_position);
    vec3 base = base_color_factor;
    if (has_map[BASE_COLOR]) base *= fetch(maps[BASE_COLOR], max_level[BASE_COLOR]);
    float metallic = metallic_factor, roughness = roughness_factor;
    if (has_map[METALLIC_ROUGHNESS]) {
        vec3 arm = fetch(maps[METALLIC_ROUGHNESS], max_level[METALLIC_ROUGHNESS]);
        metallic *= arm.b;
        roughness *= arm.g;
    }
    float occlusion = 1.0;
    if (has_map[OCCLUSION])
        occlusion = 1.0 + occlusion_strength * (fetch(maps[OCCLUSION], max_level[OCCLUSION]).r - 1.0);
    vec3 glow = emissive;
    if (has_map[EMISSIVE]) glow *= fetch(maps[EMISSIVE], max_level[EMISSIVE]);

    vec3 n = shading_normal(view);
    vec3 c_diff = base * (1.0 - metallic);
    vec3 f0 = 0.04 * (1.0 - metallic) + base * metallic;
    float alpha = pow(clamp(roughness, min_roughness, 1.0), 2.0);
    float alpha_sq = alpha * alpha;
    float nv = max(dot(n, view), 1e-4);
    vec3 radiance = ambient * occlusion * (c_diff + f0) + glow;
    for (int i = 0; i < 2; ++i) {
        vec3 l = light_direction[i];
        vec3 h = normalize(l + view);
        float nl = max(dot(n, l), 0.0);
        float nh = max(dot(n, h), 0.0);
        float vh = max(dot(view, h), 0.0);
        vec3 fresnel = f0 + (1.0 - f0) * pow(1.0 - vh, 5.0);
        float d = nh * nh * (alpha_sq - 1.0) + 1.0;
        float distribution = alpha_sq / (PI * d * d);
        float visibility = 0.5 / (nl * sqrt(nv * nv * (1.0 - alpha_sq) + alpha_sq)
                                  + nv * sqrt(nl * nl * (1.0 - alpha_sq) + alpha_sq));
        vec3 brdf = (1.0 - fresnel) * c_diff / PI + fresnel * distribution * visibility;
        radiance += light_irradiance[i] * brdf * nl;
    }
    colour = vec4(clamp(radiance, 0.0, 1.0), 1.0);
}
