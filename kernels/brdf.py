"""Microfacet surface BRDF of the deferred renderer (seed 000 §6.1, Eq. 7-12).

Vectors are unit vectors in one frame: ``n`` the shading normal, ``v`` towards the eye,
``l`` towards the light, ``h = normalize(v + l)``. ``roughness`` is the artist's
(perceptual) roughness in [0, 1]; the GGX width is ``alpha = roughness^2`` (seed 000
after Eq. 9, Burley 2012), clamped to ``ALPHA_MIN`` so D stays finite in f32.

The layered tissue material of :func:`surface_brdf_cos`::

    F0      = mix(0.04, albedo, metalness)
    diffuse = albedo (1 - metalness) / pi · Disney(n·v, n·l, l·h) · (1 - F(n·l)) (1 - F(n·v))
    base    = diffuse + F(v·h) D(n·h) V(n·v, n·l)                       Eq. 8, 9, 10, 11, 12
    coat    = F_c(v·h) D_c(n·h) V_c(n·v, n·l)          wet mucus film, F0 = 0.02, roughness 0.08
    f · n·l = [(1 - mucus F_c(n·l)) (1 - mucus F_c(n·v)) base + mucus coat] n·l

The mucus film is water (n = 1.33, F0 = ((n - 1)/(n + 1))^2 = 0.02) on the tissue, a
clear coat. Light reaches the base through the film and leaves through it again, hence
the two transmission factors (the form of Eq. 12's energy factor); one factor
1 - F_c(v·h), as in Filament's clear coat, reflected up to 1.4x the incident energy at
grazing views. Every function is f32 and runs on the CPU, CUDA and Vulkan backends.
"""

import math

import taichi as ti

PI = math.pi
INV_PI = 1.0 / math.pi
LN2 = math.log(2.0)
ALPHA_MIN = 0.002
"""Smallest GGX alpha: peak D = 1 / (pi alpha^2) ~ 8e4 stays finite in f32."""
N_DOT_MIN = 1e-4
"""n·v and n·l are clamped to this in the lobes (grazing pixels keep a finite shade)."""
DIELECTRIC_F0 = 0.04
MUCUS_F0 = 0.02
MUCUS_ROUGHNESS = 0.08


@ti.func
def ggx_distance(n_dot_h, alpha):
    """GGX (Trowbridge-Reitz) normal distribution D(h), seed 000 Eq. 9 (Walter et al.
    2007; Burley 2012): alpha^2 / (pi ((n·h)^2 (alpha^2 - 1) + 1)^2) [1/sr]."""
    a2 = ti.max(alpha, ALPHA_MIN) ** 2
    d = (1.0 - n_dot_h) * (
        1.0 + n_dot_h
    ) + a2 * n_dot_h * n_dot_h  # = (n·h)^2 (a2 - 1) + 1, exact 1 - n·h
    return a2 / (PI * d * d)


@ti.func
def smith_visibility(n_dot_v, n_dot_l, alpha):
    """Height-correlated Smith masking-shadowing as V = G2 / (4 n·l n·v), seed 000 Eq. 10.

    The seed's Eq. 10 lost the ``1 +`` of its denominator; this is Heitz 2014 Eq. 99,
    G2 = 1 / (1 + Lambda(v) + Lambda(l)) with Lambda(x) = (-1 + sqrt(1 + alpha^2 tan^2))/2,
    which gives V = 0.5 / (n·l sqrt((n·v)^2 (1 - a2) + a2) + n·v sqrt((n·l)^2 (1 - a2) + a2)).
    The Heaviside factors are the caller's n·l > 0, n·v > 0 test."""
    a2 = ti.max(alpha, ALPHA_MIN) ** 2
    lambda_v = n_dot_l * ti.sqrt(n_dot_v * n_dot_v * (1.0 - a2) + a2)
    lambda_l = n_dot_v * ti.sqrt(n_dot_l * n_dot_l * (1.0 - a2) + a2)
    return 0.5 / (lambda_v + lambda_l)


@ti.func
def fresnel_weight(cos_theta):
    """The (1 - F0) weight of seed 000 Eq. 11: the spherical-Gaussian fit of Schlick's
    (1 - cos)^5 (Tsai & Shih 2006), 2^((-5.55473 c - 6.98316) c) as in Karis 2013.

    The seed's extracted exponent (-6.745372 c^2 + 35.324156 c) is garbled (it grows with
    c); this is the published form. 2^x is computed as exp(x ln 2)."""
    return ti.exp((-5.55473 * cos_theta - 6.98316) * cos_theta * LN2)


@ti.func
def fresnel(f0, v_dot_h):
    """Fresnel reflectance F = F0 + (1 - F0) 2^((-5.55473 v·h - 6.98316) v·h), seed 000
    Eq. 11 (Tsai & Shih 2006; Karis 2013). ``f0`` is an RGB vector; returns RGB."""
    return f0 + (1.0 - f0) * fresnel_weight(v_dot_h)


@ti.func
def mucus_fresnel(cos_theta):
    """Fresnel reflectance of the water film, seed 000 Eq. 11 with F0 = 0.02 (scalar)."""
    return MUCUS_F0 + (1.0 - MUCUS_F0) * fresnel_weight(cos_theta)


@ti.func
def specular_f0(albedo, metalness):
    """Normal-incidence reflectance of the base layer: mix(0.04, albedo, metalness)."""
    return ti.math.mix(ti.Vector([DIELECTRIC_F0, DIELECTRIC_F0, DIELECTRIC_F0]), albedo, metalness)


@ti.func
def disney_diffuse(n_dot_v, n_dot_l, l_dot_h, roughness):
    """Burley's retro-reflective diffuse factor, seed 000 Eq. 12 without albedo / pi:
    (1 + (F_D90 - 1)(1 - n·l)^5)(1 + (F_D90 - 1)(1 - n·v)^5).

    The seed's F_D90 = 0.5 + cos(l·h)^2 alpha is garbled; this uses Burley 2012 §5.3,
    F_D90 = 0.5 + 2 roughness (l·h)^2 with the perceptual roughness."""
    fd90_minus_1 = 2.0 * roughness * l_dot_h * l_dot_h - 0.5
    ml = 1.0 - n_dot_l
    mv = 1.0 - n_dot_v
    ml2 = ml * ml
    mv2 = mv * mv
    return (1.0 + fd90_minus_1 * ml2 * ml2 * ml) * (1.0 + fd90_minus_1 * mv2 * mv2 * mv)


@ti.func
def surface_brdf_cos(n, v, l, albedo, roughness, metalness, mucus):
    """f(v, l) n·l of the layered tissue material for one light direction (seed 000
    Eq. 8-12; the layering is in the module docstring). ``albedo`` RGB in [0, 1],
    ``roughness``, ``metalness`` and ``mucus`` (film coverage) in [0, 1]. Returns RGB
    [1/sr]: outgoing radiance = result · E, E the light's irradiance normal to l (a point
    light of intensity I [W/sr] at distance d: E = I / d^2). Zero when n·l <= 0 or
    n·v <= 0; inside, both are clamped to N_DOT_MIN."""
    result = ti.Vector([0.0, 0.0, 0.0])
    n_dot_l = n.dot(l)
    n_dot_v = n.dot(v)
    if n_dot_l > 0.0 and n_dot_v > 0.0:
        nl = ti.max(n_dot_l, N_DOT_MIN)
        nv = ti.max(n_dot_v, N_DOT_MIN)
        h = (v + l).normalized(1e-12)
        n_dot_h = ti.max(n.dot(h), 0.0)
        v_dot_h = ti.max(v.dot(h), 0.0)
        alpha = roughness * roughness
        f0 = specular_f0(albedo, metalness)
        # one Eq. 11 weight per cosine, shared by the base and the film
        w_l, w_v, w_h = fresnel_weight(nl), fresnel_weight(nv), fresnel_weight(v_dot_h)
        diffuse = (
            albedo
            * ((1.0 - metalness) * INV_PI * disney_diffuse(nv, nl, v_dot_h, roughness))
            * ((1.0 - f0) * (1.0 - w_l))
            * ((1.0 - f0) * (1.0 - w_v))
        )
        specular = (f0 + (1.0 - f0) * w_h) * (
            ggx_distance(n_dot_h, alpha) * smith_visibility(nv, nl, alpha)
        )
        coat_alpha = MUCUS_ROUGHNESS * MUCUS_ROUGHNESS
        coat = (
            (MUCUS_F0 + (1.0 - MUCUS_F0) * w_h)
            * ggx_distance(n_dot_h, coat_alpha)
            * smith_visibility(nv, nl, coat_alpha)
        )
        transmission = (1.0 - mucus * (MUCUS_F0 + (1.0 - MUCUS_F0) * w_l)) * (
            1.0 - mucus * (MUCUS_F0 + (1.0 - MUCUS_F0) * w_v)
        )
        result = (transmission * (diffuse + specular) + mucus * coat) * n_dot_l
    return result


NORMAL_FRESNEL_WEIGHT = math.exp((-5.55473 - 6.98316) * LN2)
"""fresnel_weight(1): the Eq. 11 weight at v·h = 1, where a headlight's h is v."""


@ti.func
def headlight_brdf_cos(n, v, albedo, roughness, metalness, mucus):
    """:func:`surface_brdf_cos` for a light at the eye, l = v (the endoscope's
    headlight): h = v, so v·h = 1, n·h = n·l = n·v, and the terms shared by l and v
    are evaluated once (two Eq. 11 weights and two Smith square roots fewer). Same
    arguments and result, up to f32 rounding."""
    result = ti.Vector([0.0, 0.0, 0.0])
    n_dot_v = n.dot(v)
    if n_dot_v > 0.0:
        c = ti.max(n_dot_v, N_DOT_MIN)
        alpha = roughness * roughness
        f0 = specular_f0(albedo, metalness)
        w = fresnel_weight(c)
        mv = 1.0 - c
        mv2 = mv * mv
        retro = 1.0 + (2.0 * roughness - 0.5) * mv2 * mv2 * mv  # disney_diffuse(c, c, 1)
        through = (1.0 - f0) * (1.0 - w)
        diffuse = albedo * ((1.0 - metalness) * INV_PI * retro * retro) * through * through
        a2 = ti.max(alpha, ALPHA_MIN) ** 2
        specular = (f0 + (1.0 - f0) * NORMAL_FRESNEL_WEIGHT) * (
            ggx_distance(n_dot_v, alpha) * (0.25 / (c * ti.sqrt(c * c * (1.0 - a2) + a2)))
        )
        coat_a2 = ti.max(MUCUS_ROUGHNESS * MUCUS_ROUGHNESS, ALPHA_MIN) ** 2
        coat = (
            (MUCUS_F0 + (1.0 - MUCUS_F0) * NORMAL_FRESNEL_WEIGHT)
            * ggx_distance(n_dot_v, MUCUS_ROUGHNESS * MUCUS_ROUGHNESS)
            * (0.25 / (c * ti.sqrt(c * c * (1.0 - coat_a2) + coat_a2)))
        )
        film = 1.0 - mucus * (MUCUS_F0 + (1.0 - MUCUS_F0) * w)
        result = (film * film * (diffuse + specular) + mucus * coat) * n_dot_v
    return result
