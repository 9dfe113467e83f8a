//! Built-in scenes, named `builtin:NAME` or `builtin:NAME?key=value&key=value`.
//!
//! | name | geometry | parameters (default) |
//! |---|---|---|
//! | `cornell` | the Cornell box from Cornell's published measurements, in metres | `scale` (1) |
//! | `sphere` | analytic closed sphere at the origin, seen from inside | `albedo` (0.5), `radius` (1) |
//! | `sphere-mesh` | tessellated closed sphere (icosphere) | `albedo` (0.5), `radius` (1), `subdivisions` (3, 0..=7) |
//! | `box` | closed axis-aligned cube at the origin, seen from inside | `albedo` (0.5), `size` (1) |
//! | `quad` | one square in the `y = 0` plane facing +Y | `albedo` (0.5), `size` (1) |
//! | `triangle` | one triangle in the `y = 0` plane facing +Y | `albedo` (0.5) |
//! | `rooms` | two rooms 4 m deep side by side (8 x 2.5 x 4 m in all), divided by a thin partition with a doorway at the far end; the light in the left room 10 cm from the partition, the camera in the right one looking at it | `albedo` (0.5), `thickness` (0.02), `door` (0.8 m wide; 0 seals the dark room) |
//!
//! `albedo` is one grey value or `r,g,b`, each finite and non-negative (values ≥ 1 load, with a
//! warning; the bake rejects them). The content hash is the xxh3-64 of a canonical string:
//! the name and *every* parameter (defaults included) sorted by key, so `sphere` and
//! `sphere?albedo=0.5` are the same scene.

use std::collections::{BTreeMap, HashMap};

use glam::Vec3;

use crate::error::SceneError;
use crate::manifest::{CameraDesc, LightDesc, LightKind, SpotFalloff};
use crate::mesh::{Material, Mesh};
use crate::scene::{Geometry, Scene};

/// Version tag mixed into the hash; bump when a built-in's geometry or defaults change.
const CANONICAL_VERSION: &str = "mlt-builtin-v1";

/// Names and valid parameter keys of the built-ins.
const BUILTINS: &[(&str, &[&str])] = &[
    ("cornell", &["scale"]),
    ("sphere", &["albedo", "radius"]),
    ("sphere-mesh", &["albedo", "radius", "subdivisions"]),
    ("box", &["albedo", "size"]),
    ("quad", &["albedo", "size"]),
    ("triangle", &["albedo"]),
    ("rooms", &["albedo", "thickness", "door"]),
];

/// Loads the built-in scene `rest` (what follows `builtin:`).
pub fn load_builtin(rest: &str) -> Result<Scene, SceneError> {
    let (name, query) = rest.split_once('?').unwrap_or((rest, ""));
    let name = name.trim();
    let Some(&(_, keys)) = BUILTINS.iter().find(|(n, _)| *n == name) else {
        let names: Vec<&str> = BUILTINS.iter().map(|(n, _)| *n).collect();
        return Err(SceneError::Builtin {
            name: name.to_string(),
            message: format!("unknown built-in scene; valid names: {}", names.join(", ")),
        });
    };
    let mut params = Params::parse(name, query, keys)?;
    let mut built = match name {
        "cornell" => cornell(&mut params)?,
        "sphere" => sphere(&mut params)?,
        "sphere-mesh" => sphere_mesh(&mut params)?,
        "box" => cube(&mut params)?,
        "quad" => quad(&mut params)?,
        "rooms" => rooms(&mut params)?,
        _ => triangle(&mut params)?,
    };
    if let Geometry::Mesh(mesh) = &mut built.geometry {
        let path = std::path::PathBuf::from(format!("builtin:{rest}"));
        mesh.drop_degenerate_triangles(&path);
        mesh.validate(&path)?;
    }
    let canonical = params.canonical();
    Ok(Scene {
        source: format!("builtin:{rest}"),
        content_hash: xxhash_rust::xxh3::xxh3_64(canonical.as_bytes()),
        geometry: built.geometry,
        viewpoint: built.viewpoint,
        camera: built.camera,
        light: built.light,
        bake: toml::Table::new(),
        scale: built.scale,
        warnings: params.warnings,
    })
}

/// What each built-in constructs (the rest of [`Scene`] is filled in by [`load_builtin`]).
struct Built {
    geometry: Geometry,
    viewpoint: Vec3,
    camera: CameraDesc,
    light: LightDesc,
    scale: f32,
}

/// Parsed `key=value` parameters; getters validate, apply defaults and record the canonical
/// value of every parameter the scene uses.
struct Params {
    name: String,
    keys: &'static [&'static str],
    given: HashMap<String, String>,
    canonical: BTreeMap<&'static str, String>,
    warnings: Vec<String>,
}

impl Params {
    fn parse(name: &str, query: &str, keys: &'static [&'static str]) -> Result<Params, SceneError> {
        let mut p = Params {
            name: name.to_string(),
            keys,
            given: HashMap::new(),
            canonical: BTreeMap::new(),
            warnings: Vec::new(),
        };
        for pair in query.split('&').filter(|s| !s.trim().is_empty()) {
            let Some((k, v)) = pair.split_once('=') else {
                return Err(p.error(format!("parameter '{pair}' is not key=value")));
            };
            let k = k.trim();
            if !keys.contains(&k) {
                return Err(p.error(format!("unknown parameter '{k}'")));
            }
            if p.given
                .insert(k.to_string(), v.trim().to_string())
                .is_some()
            {
                return Err(p.error(format!("parameter '{k}' given twice")));
            }
        }
        Ok(p)
    }

    fn error(&self, message: String) -> SceneError {
        let valid = if self.keys.is_empty() {
            "none".to_string()
        } else {
            self.keys.join(", ")
        };
        SceneError::Builtin {
            name: self.name.clone(),
            message: format!("{message} (valid parameters: {valid})"),
        }
    }

    fn parse_f32(&self, key: &str, text: &str) -> Result<f32, SceneError> {
        let x: f32 = text
            .parse()
            .map_err(|_| self.error(format!("{key}={text} is not a number")))?;
        if !x.is_finite() {
            return Err(self.error(format!("{key}={text} is not finite")));
        }
        Ok(x)
    }

    /// A finite number `> 0`.
    fn positive(&mut self, key: &'static str, default: f32) -> Result<f32, SceneError> {
        let x = match self.given.get(key) {
            Some(text) => self.parse_f32(key, text)?,
            None => default,
        };
        if x <= 0.0 {
            return Err(self.error(format!("{key}={x} must be > 0")));
        }
        self.canonical.insert(key, format!("{x:?}"));
        Ok(x)
    }

    /// A finite number `>= 0` and below `max`.
    fn in_range(&mut self, key: &'static str, default: f32, max: f32) -> Result<f32, SceneError> {
        let x = match self.given.get(key) {
            Some(text) => self.parse_f32(key, text)?,
            None => default,
        };
        if !(0.0..max).contains(&x) {
            return Err(self.error(format!("{key}={x} must be at least 0 and below {max}")));
        }
        self.canonical.insert(key, format!("{x:?}"));
        Ok(x)
    }

    /// An integer in `range`.
    fn integer(
        &mut self,
        key: &'static str,
        default: u32,
        range: std::ops::RangeInclusive<u32>,
    ) -> Result<u32, SceneError> {
        let x = match self.given.get(key) {
            Some(text) => text
                .parse::<u32>()
                .map_err(|_| self.error(format!("{key}={text} is not a non-negative integer")))?,
            None => default,
        };
        if !range.contains(&x) {
            return Err(self.error(format!(
                "{key}={x} is outside {}..={}",
                range.start(),
                range.end()
            )));
        }
        self.canonical.insert(key, x.to_string());
        Ok(x)
    }

    /// `albedo`: one grey value or `r,g,b`; finite and non-negative (≥ 1 only warned about).
    fn albedo(&mut self) -> Result<[f32; 3], SceneError> {
        const KEY: &str = "albedo";
        let rgb = match self.given.get(KEY) {
            None => [0.5; 3],
            Some(text) => {
                let parts: Vec<&str> = text.split(',').collect();
                let values = parts
                    .iter()
                    .map(|s| self.parse_f32(KEY, s.trim()))
                    .collect::<Result<Vec<f32>, _>>()?;
                match values[..] {
                    [g] => [g; 3],
                    [r, g, b] => [r, g, b],
                    _ => {
                        return Err(
                            self.error(format!("albedo={text}: give one value or three (r,g,b)"))
                        )
                    }
                }
            }
        };
        if rgb.iter().any(|&c| c < 0.0) {
            return Err(self.error(format!("albedo {rgb:?} must not be negative")));
        }
        if rgb.iter().any(|&c| c >= 1.0) {
            let message = format!(
                "builtin:{}: albedo {rgb:?} is not below 1 (no energy is lost; baking will refuse it)",
                self.name
            );
            log::warn!("{message}");
            self.warnings.push(message);
        }
        self.canonical
            .insert(KEY, format!("{:?},{:?},{:?}", rgb[0], rgb[1], rgb[2]));
        Ok(rgb)
    }

    /// `CANONICAL_VERSION:name?k=v&...` with every parameter, sorted by key.
    fn canonical(&self) -> String {
        let params: Vec<String> = self
            .canonical
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect();
        format!("{CANONICAL_VERSION}:{}?{}", self.name, params.join("&"))
    }
}

fn point_light(position: Vec3, intensity: f32) -> LightDesc {
    LightDesc {
        kind: LightKind::Point,
        position: position.to_array(),
        intensity: [intensity; 3],
        direction: None,
        cone_deg: None,
        falloff: SpotFalloff::Hard,
    }
}

fn camera(position: Vec3, target: Vec3, up: Vec3, fovy_deg: f32) -> CameraDesc {
    CameraDesc {
        position: position.to_array(),
        target: target.to_array(),
        up: up.to_array(),
        fovy_deg,
        width: 512,
        height: 512,
    }
}

/// A mesh with one material, built from triangles given as corner positions.
fn mesh_from_triangles(
    tris: &[[Vec3; 3]],
    materials: Vec<Material>,
    triangle_material: Vec<u32>,
) -> Mesh {
    let mut mesh = Mesh {
        materials,
        triangle_material,
        ..Default::default()
    };
    for t in tris {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend_from_slice(t);
        mesh.triangles.push([base, base + 1, base + 2]);
    }
    mesh
}

/// Two triangles for the planar quad `q` (corners in order), wound so that the face normal
/// points towards `toward` (a point in front of the face).
fn oriented_quad(q: [Vec3; 4], toward: Vec3) -> [[Vec3; 3]; 2] {
    let centre = (q[0] + q[1] + q[2] + q[3]) * 0.25;
    let n = (q[1] - q[0]).cross(q[2] - q[0]);
    let q = if n.dot(toward - centre) >= 0.0 {
        q
    } else {
        [q[3], q[2], q[1], q[0]]
    };
    [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
}

/// The Cornell box (Cornell University Program of Computer Graphics, "Cornell Box data"),
/// millimetres converted to metres. The area light is replaced by a point light just below
/// the ceiling, which is one full quad; the blocks have no bottom faces.
fn cornell(p: &mut Params) -> Result<Built, SceneError> {
    let s = p.positive("scale", 1.0)?;
    let mm = |x: f32, y: f32, z: f32| Vec3::new(x, y, z) * (0.001 * s);
    let white = Material::plain("white", [0.725, 0.71, 0.68]);
    let red = Material::plain("red", [0.63, 0.065, 0.05]);
    let green = Material::plain("green", [0.14, 0.45, 0.091]);
    let room_centre = mm(278.0, 274.4, 279.6);

    let room: [([Vec3; 4], u32); 5] = [
        // floor
        (
            [
                mm(552.8, 0.0, 0.0),
                mm(0.0, 0.0, 0.0),
                mm(0.0, 0.0, 559.2),
                mm(549.6, 0.0, 559.2),
            ],
            0,
        ),
        // ceiling
        (
            [
                mm(556.0, 548.8, 0.0),
                mm(556.0, 548.8, 559.2),
                mm(0.0, 548.8, 559.2),
                mm(0.0, 548.8, 0.0),
            ],
            0,
        ),
        // back wall
        (
            [
                mm(549.6, 0.0, 559.2),
                mm(0.0, 0.0, 559.2),
                mm(0.0, 548.8, 559.2),
                mm(556.0, 548.8, 559.2),
            ],
            0,
        ),
        // right wall (green, x = 0)
        (
            [
                mm(0.0, 0.0, 559.2),
                mm(0.0, 0.0, 0.0),
                mm(0.0, 548.8, 0.0),
                mm(0.0, 548.8, 559.2),
            ],
            2,
        ),
        // left wall (red, x ≈ 550..556)
        (
            [
                mm(552.8, 0.0, 0.0),
                mm(549.6, 0.0, 559.2),
                mm(556.0, 548.8, 559.2),
                mm(556.0, 548.8, 0.0),
            ],
            1,
        ),
    ];
    let [short_block, tall_block] = cornell_blocks(mm);

    let mut tris = Vec::new();
    let mut mats = Vec::new();
    for (q, m) in room {
        tris.extend(oriented_quad(q, room_centre));
        mats.extend([m, m]);
    }
    for block in [short_block, tall_block] {
        let corners: Vec<Vec3> = block.iter().flatten().copied().collect();
        let centre = corners.iter().copied().sum::<Vec3>() / corners.len() as f32;
        for q in block {
            let face_centre = (q[0] + q[1] + q[2] + q[3]) * 0.25;
            // Outward: towards a point beyond the face, away from the block centre.
            tris.extend(oriented_quad(q, 2.0 * face_centre - centre));
            mats.extend([0, 0]);
        }
    }
    let mesh = mesh_from_triangles(&tris, vec![white, red, green], mats);
    Ok(Built {
        geometry: Geometry::Mesh(mesh),
        // Not the room's centre (0.278, 0.274, 0.28): that is 1.2 cm from the tall block's
        // corner. This is the viewpoint of the OBJ Cornell box's manifest, (0, 1, 0.5), mapped
        // into these coordinates: mid-height, in front of the blocks, 11 cm above the short one.
        viewpoint: Vec3::new(0.278, 0.274, 0.15) * s,
        camera: camera(
            Vec3::new(0.278, 0.273, -0.8) * s,
            Vec3::new(0.278, 0.273, 0.0) * s,
            Vec3::Y,
            39.3,
        ),
        // 0.5 W/sr gives E = I/d² ≈ 1.8 on the floor right below (d = 0.54 m).
        light: point_light(Vec3::new(0.278, 0.5438, 0.2795) * s, 0.5),
        scale: 0.001 * s,
    })
}

/// The Cornell box's short and tall blocks, five faces of four corners each (the published
/// data, in millimetres through `mm`).
fn cornell_blocks(mm: impl Fn(f32, f32, f32) -> Vec3) -> [[[Vec3; 4]; 5]; 2] {
    let short_block = [
        [
            mm(130.0, 165.0, 65.0),
            mm(82.0, 165.0, 225.0),
            mm(240.0, 165.0, 272.0),
            mm(290.0, 165.0, 114.0),
        ],
        [
            mm(290.0, 0.0, 114.0),
            mm(290.0, 165.0, 114.0),
            mm(240.0, 165.0, 272.0),
            mm(240.0, 0.0, 272.0),
        ],
        [
            mm(130.0, 0.0, 65.0),
            mm(130.0, 165.0, 65.0),
            mm(290.0, 165.0, 114.0),
            mm(290.0, 0.0, 114.0),
        ],
        [
            mm(82.0, 0.0, 225.0),
            mm(82.0, 165.0, 225.0),
            mm(130.0, 165.0, 65.0),
            mm(130.0, 0.0, 65.0),
        ],
        [
            mm(240.0, 0.0, 272.0),
            mm(240.0, 165.0, 272.0),
            mm(82.0, 165.0, 225.0),
            mm(82.0, 0.0, 225.0),
        ],
    ];
    let tall_block = [
        [
            mm(423.0, 330.0, 247.0),
            mm(265.0, 330.0, 296.0),
            mm(314.0, 330.0, 456.0),
            mm(472.0, 330.0, 406.0),
        ],
        [
            mm(423.0, 0.0, 247.0),
            mm(423.0, 330.0, 247.0),
            mm(472.0, 330.0, 406.0),
            mm(472.0, 0.0, 406.0),
        ],
        [
            mm(472.0, 0.0, 406.0),
            mm(472.0, 330.0, 406.0),
            mm(314.0, 330.0, 456.0),
            mm(314.0, 0.0, 456.0),
        ],
        [
            mm(314.0, 0.0, 456.0),
            mm(314.0, 330.0, 456.0),
            mm(265.0, 330.0, 296.0),
            mm(265.0, 0.0, 296.0),
        ],
        [
            mm(265.0, 0.0, 296.0),
            mm(265.0, 330.0, 296.0),
            mm(423.0, 330.0, 247.0),
            mm(423.0, 0.0, 247.0),
        ],
    ];
    [short_block, tall_block]
}

/// Camera at the centre of a closed scene, looking along -Z.
fn inside_camera() -> CameraDesc {
    camera(Vec3::ZERO, -Vec3::Z, Vec3::Y, 90.0)
}

fn sphere(p: &mut Params) -> Result<Built, SceneError> {
    let albedo = p.albedo()?;
    let radius = p.positive("radius", 1.0)?;
    Ok(Built {
        geometry: Geometry::Sphere {
            center: Vec3::ZERO,
            radius,
            albedo,
        },
        viewpoint: Vec3::ZERO,
        camera: inside_camera(),
        light: point_light(Vec3::ZERO, 1.0),
        scale: 1.0,
    })
}

fn sphere_mesh(p: &mut Params) -> Result<Built, SceneError> {
    let albedo = p.albedo()?;
    let radius = p.positive("radius", 1.0)?;
    let subdivisions = p.integer("subdivisions", 3, 0..=7)?;
    Ok(Built {
        geometry: Geometry::Mesh(icosphere(radius, subdivisions, albedo)),
        viewpoint: Vec3::ZERO,
        camera: inside_camera(),
        light: point_light(Vec3::ZERO, 1.0),
        scale: 1.0,
    })
}

/// A closed icosphere of `radius` around the origin (`20 · 4^subdivisions` triangles, wound
/// outward), with the exact sphere normals as vertex normals.
pub fn icosphere(radius: f32, subdivisions: u32, albedo: [f32; 3]) -> Mesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut verts: Vec<Vec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|v| Vec3::from_array(*v).normalize())
    .collect();
    let mut faces: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdivisions {
        let mut midpoint: HashMap<(u32, u32), u32> = HashMap::new();
        let mut mid = |a: u32, b: u32, verts: &mut Vec<Vec3>| -> u32 {
            let key = (a.min(b), a.max(b));
            *midpoint.entry(key).or_insert_with(|| {
                verts.push((verts[a as usize] + verts[b as usize]).normalize());
                (verts.len() - 1) as u32
            })
        };
        let mut next = Vec::with_capacity(faces.len() * 4);
        for [a, b, c] in faces {
            let ab = mid(a, b, &mut verts);
            let bc = mid(b, c, &mut verts);
            let ca = mid(c, a, &mut verts);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        faces = next;
    }
    Mesh {
        positions: verts.iter().map(|v| *v * radius).collect(),
        normals: verts,
        uvs: Vec::new(),
        triangle_material: vec![0; faces.len()],
        triangles: faces,
        materials: vec![Material::plain("sphere", albedo)],
        textures: Vec::new(),
        degenerate_dropped: 0,
    }
}

fn cube(p: &mut Params) -> Result<Built, SceneError> {
    let albedo = p.albedo()?;
    let size = p.positive("size", 1.0)?;
    let h = 0.5 * size;
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z) * h;
    let faces = [
        [
            c(-1., -1., -1.),
            c(1., -1., -1.),
            c(1., -1., 1.),
            c(-1., -1., 1.),
        ],
        [
            c(-1., 1., -1.),
            c(1., 1., -1.),
            c(1., 1., 1.),
            c(-1., 1., 1.),
        ],
        [
            c(-1., -1., -1.),
            c(-1., 1., -1.),
            c(-1., 1., 1.),
            c(-1., -1., 1.),
        ],
        [
            c(1., -1., -1.),
            c(1., 1., -1.),
            c(1., 1., 1.),
            c(1., -1., 1.),
        ],
        [
            c(-1., -1., -1.),
            c(1., -1., -1.),
            c(1., 1., -1.),
            c(-1., 1., -1.),
        ],
        [
            c(-1., -1., 1.),
            c(1., -1., 1.),
            c(1., 1., 1.),
            c(-1., 1., 1.),
        ],
    ];
    let tris: Vec<[Vec3; 3]> = faces
        .iter()
        .flat_map(|q| oriented_quad(*q, Vec3::ZERO))
        .collect();
    let mesh = mesh_from_triangles(&tris, vec![Material::plain("box", albedo)], vec![0; 12]);
    Ok(Built {
        geometry: Geometry::Mesh(mesh),
        viewpoint: Vec3::ZERO,
        camera: inside_camera(),
        // E = I / d² = 1 at the centre of each face (d = size / 2).
        light: point_light(Vec3::ZERO, h * h),
        scale: 1.0,
    })
}

fn quad(p: &mut Params) -> Result<Built, SceneError> {
    let albedo = p.albedo()?;
    let size = p.positive("size", 1.0)?;
    let h = 0.5 * size;
    let q = [
        Vec3::new(-h, 0.0, -h),
        Vec3::new(-h, 0.0, h),
        Vec3::new(h, 0.0, h),
        Vec3::new(h, 0.0, -h),
    ];
    let tris = oriented_quad(q, Vec3::Y);
    let mesh = mesh_from_triangles(&tris, vec![Material::plain("quad", albedo)], vec![0; 2]);
    Ok(Built {
        geometry: Geometry::Mesh(mesh),
        viewpoint: Vec3::new(0.0, 0.5 * size, 0.0),
        camera: camera(Vec3::new(0.0, 1.5 * size, 0.0), Vec3::ZERO, -Vec3::Z, 60.0),
        // E = 1 right below the light (d = size / 2).
        light: point_light(Vec3::new(0.0, 0.5 * size, 0.0), h * h),
        scale: 1.0,
    })
}

fn triangle(p: &mut Params) -> Result<Built, SceneError> {
    let albedo = p.albedo()?;
    let tri = [
        Vec3::new(-0.5, 0.0, -0.5),
        Vec3::new(0.0, 0.0, 0.5),
        Vec3::new(0.5, 0.0, -0.5),
    ];
    let mesh = mesh_from_triangles(&[tri], vec![Material::plain("triangle", albedo)], vec![0]);
    Ok(Built {
        geometry: Geometry::Mesh(mesh),
        viewpoint: Vec3::new(0.0, 0.5, 0.0),
        camera: camera(Vec3::new(0.0, 1.5, 0.0), Vec3::ZERO, -Vec3::Z, 60.0),
        light: point_light(Vec3::new(0.0, 0.5, 0.0), 0.25),
        scale: 1.0,
    })
}

/// Interior size of [`rooms`]: width (both rooms), height, depth.
const ROOMS: [f32; 3] = [8.0, 2.5, 4.0];

/// Two rooms side by side (x < 0 and x > 0), divided by a partition `thickness` thick at
/// x = 0 that runs from the front wall (z = 0) to a doorway `door` wide at the back
/// (z = 4 - door .. 4; `door = 0` seals the right room): the thin-wall case where light must
/// stay on its side. The outer shell faces inward; the partition's two sides and its end
/// face outward. The light is in the left room, 10 cm from the partition; the camera in the
/// right room looks at the partition.
fn rooms(p: &mut Params) -> Result<Built, SceneError> {
    let albedo = p.albedo()?;
    let t = p.positive("thickness", 0.02)?;
    if t >= 1.0 {
        return Err(p.error(format!(
            "thickness={t} must be below 1 (the rooms are 4 m wide)"
        )));
    }
    let door = p.in_range("door", 0.8, ROOMS[2])?;
    let [w, h, d] = ROOMS;
    let (x0, x1) = (-0.5 * w, 0.5 * w);
    let v = Vec3::new;
    let inside = v(0.0, 0.5 * h, 0.5 * d);
    let mut tris: Vec<[Vec3; 3]> = Vec::new();
    // The shell: floor, ceiling, front, back, left, right, facing the inside.
    for q in [
        [v(x0, 0., 0.), v(x1, 0., 0.), v(x1, 0., d), v(x0, 0., d)],
        [v(x0, h, 0.), v(x1, h, 0.), v(x1, h, d), v(x0, h, d)],
        [v(x0, 0., 0.), v(x1, 0., 0.), v(x1, h, 0.), v(x0, h, 0.)],
        [v(x0, 0., d), v(x1, 0., d), v(x1, h, d), v(x0, h, d)],
        [v(x0, 0., 0.), v(x0, h, 0.), v(x0, h, d), v(x0, 0., d)],
        [v(x1, 0., 0.), v(x1, h, 0.), v(x1, h, d), v(x1, 0., d)],
    ] {
        tris.extend(oriented_quad(q, inside));
    }
    // The partition: its two sides and, with a doorway, its end.
    let (a, b, end) = (-0.5 * t, 0.5 * t, d - door);
    tris.extend(oriented_quad(
        [v(a, 0., 0.), v(a, h, 0.), v(a, h, end), v(a, 0., end)],
        v(x0, 0.5 * h, 0.5 * end),
    ));
    tris.extend(oriented_quad(
        [v(b, 0., 0.), v(b, h, 0.), v(b, h, end), v(b, 0., end)],
        v(x1, 0.5 * h, 0.5 * end),
    ));
    if door > 0.0 {
        tris.extend(oriented_quad(
            [v(a, 0., end), v(b, 0., end), v(b, h, end), v(a, h, end)],
            v(0.0, 0.5 * h, d),
        ));
    }
    let n = tris.len();
    let mesh = mesh_from_triangles(&tris, vec![Material::plain("walls", albedo)], vec![0; n]);
    let mut camera = camera(v(3.6, 1.4, 2.0), v(0.0, 1.2, 2.0), Vec3::Y, 70.0);
    (camera.width, camera.height) = (320, 180);
    Ok(Built {
        geometry: Geometry::Mesh(mesh),
        // In the lit room: its particles reach the dark one through the doorway.
        viewpoint: v(-2.0, 1.25, 2.0),
        camera,
        // E = I / d^2 = 1 on the floor 1.5 m below.
        light: point_light(v(a - 0.1, 1.5, 2.0), 2.25),
        scale: 1.0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raycast::RayCaster;

    #[test]
    fn rooms_are_closed_divided_and_open_only_at_the_doorway() {
        let s = load_builtin("rooms").expect("loads");
        let caster = s.build_caster();
        let light = Vec3::from(s.light.position);
        let cam = Vec3::from(s.camera.position);
        // The partition blocks the straight line from the light to the camera...
        assert!(caster.occluded(light, cam));
        // ...the doorway lets a line through at its height...
        assert!(!caster.occluded(Vec3::new(-1.0, 1.0, 3.6), Vec3::new(1.0, 1.0, 3.6)));
        // ...and sealed it does not.
        let sealed = load_builtin("rooms?door=0").expect("loads").build_caster();
        assert!(sealed.occluded(Vec3::new(-1.0, 1.0, 3.6), Vec3::new(1.0, 1.0, 3.6)));
        // Every ray from inside either room hits something (closed), a face turned toward it.
        let mesh = mesh_of(&s);
        for origin in [cam, light] {
            for k in 0..64 {
                let a = k as f32 * 0.7;
                let dir = Vec3::new(a.cos(), 0.3 * (1.3 * a).sin(), a.sin()).normalize();
                let hit = caster
                    .intersect(origin, dir, 0.0, f32::INFINITY)
                    .expect("the rooms are closed");
                let t = mesh.triangles[hit.prim_id as usize].map(|i| mesh.positions[i as usize]);
                let n = (t[1] - t[0]).cross(t[2] - t[0]);
                assert!(
                    n.dot(dir) < 0.0,
                    "a face turned away at ray {k} from {origin}"
                );
            }
        }
        for bad in ["rooms?thickness=1", "rooms?door=4", "rooms?door=-1"] {
            assert!(load_builtin(bad).is_err(), "{bad}");
        }
    }

    fn mesh_of(scene: &Scene) -> &Mesh {
        match &scene.geometry {
            Geometry::Mesh(m) => m,
            Geometry::Sphere { .. } => panic!("expected a mesh"),
        }
    }

    #[test]
    fn unknown_names_keys_and_values_are_errors() {
        let cases = [
            ("teapot", "valid names"),
            ("sphere?colour=1", "unknown parameter 'colour'"),
            ("sphere?albedo=-0.1", "must not be negative"),
            ("sphere?albedo=NaN", "not finite"),
            ("sphere?albedo=abc", "not a number"),
            ("sphere?albedo=0.1,0.2", "three"),
            ("sphere?radius=0", "must be > 0"),
            ("sphere?radius=1&radius=2", "twice"),
            ("sphere?radius", "key=value"),
            ("sphere-mesh?subdivisions=9", "outside"),
            ("cornell?albedo=0.5", "unknown parameter"),
        ];
        for (spec, needle) in cases {
            let e = load_builtin(spec).expect_err(spec);
            assert!(matches!(e, SceneError::Builtin { .. }), "{spec}: {e}");
            let msg = e.to_string();
            assert!(msg.contains(needle), "{spec}: {msg}");
            if spec.contains('?') {
                assert!(msg.contains("valid parameters"), "{spec}: {msg}");
            }
        }
    }

    #[test]
    fn params_are_applied_and_hashed_canonically() {
        let s = load_builtin("sphere?radius=2.5&albedo=0.3,0.4,0.5").expect("loads");
        match s.geometry {
            Geometry::Sphere { radius, albedo, .. } => {
                assert_eq!(radius, 2.5);
                assert_eq!(albedo, [0.3, 0.4, 0.5]);
            }
            Geometry::Mesh(_) => panic!("expected the analytic sphere"),
        }
        assert_eq!(s.source, "builtin:sphere?radius=2.5&albedo=0.3,0.4,0.5");
        let reordered = load_builtin("sphere?albedo=0.3,0.4,0.5&radius=2.5").expect("loads");
        assert_eq!(s.content_hash, reordered.content_hash);
        let defaults = load_builtin("sphere").expect("loads");
        let explicit = load_builtin("sphere?albedo=0.5&radius=1").expect("loads");
        assert_eq!(defaults.content_hash, explicit.content_hash);
        assert_ne!(defaults.content_hash, s.content_hash);
        // Albedo ≥ 1 loads with a warning.
        let white = load_builtin("sphere?albedo=1").expect("loads");
        assert_eq!(white.warnings.len(), 1);

        let b = load_builtin("box?size=4").expect("loads");
        let (lo, hi) = mesh_of(&b).bounds();
        assert_eq!((lo, hi), (Vec3::splat(-2.0), Vec3::splat(2.0)));
        assert_eq!(mesh_of(&b).triangles.len(), 12);
        let sm = load_builtin("sphere-mesh?subdivisions=2").expect("loads");
        assert_eq!(mesh_of(&sm).triangles.len(), 320);
        assert_eq!(
            mesh_of(&load_builtin("quad").expect("loads"))
                .triangles
                .len(),
            2
        );
        assert_eq!(
            mesh_of(&load_builtin("triangle").expect("loads"))
                .triangles
                .len(),
            1
        );
    }

    #[test]
    fn box_faces_point_inward_and_quad_faces_up() {
        let b = load_builtin("box").expect("loads");
        let m = mesh_of(&b);
        for t in 0..m.triangles.len() as u32 {
            let [a, b, c] = m.corners(t);
            let n = (b - a).cross(c - a);
            assert!(
                n.dot(-(a + b + c) / 3.0) > 0.0,
                "triangle {t} faces outward"
            );
        }
        let q = load_builtin("quad").expect("loads");
        let [a, b, c] = mesh_of(&q).corners(0);
        assert!((b - a).cross(c - a).y > 0.0);
    }

    #[test]
    fn cornell_box_matches_the_published_data() {
        let s = load_builtin("cornell").expect("loads");
        let m = mesh_of(&s);
        assert_eq!(m.triangles.len(), 30);
        let (lo, hi) = m.bounds();
        assert!((lo - Vec3::ZERO).length() < 1e-6);
        assert!(
            (hi - Vec3::new(0.556, 0.5488, 0.5592)).length() < 1e-6,
            "{hi}"
        );
        assert!((s.scale - 0.001).abs() < 1e-9);
        // Room faces point into the room; the light is inside and below the ceiling.
        let caster = crate::mesh_caster::MeshCaster::new(m.clone());
        let light = Vec3::from(s.light.position);
        let up = caster
            .intersect(light, Vec3::Y, 0.0, f32::INFINITY)
            .expect("ceiling above the light");
        assert!((up.position.y - 0.5488).abs() < 1e-6 && up.t < 0.01);
        // Looking left (+X) from above the blocks hits the red wall, right (-X) the green one.
        let vp = Vec3::new(s.viewpoint.x, 0.45, s.viewpoint.z);
        let left = caster
            .intersect(vp, Vec3::X, 0.0, f32::INFINITY)
            .expect("red wall");
        assert_eq!(left.albedo, [0.63, 0.065, 0.05]);
        let right = caster
            .intersect(vp, -Vec3::X, 0.0, f32::INFINITY)
            .expect("green wall");
        assert_eq!(right.albedo, [0.14, 0.45, 0.091]);
        // The viewpoint is clear of every surface by more than 10 cm (the short block's top
        // is nearest); the front is open.
        for d in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z] {
            let h = caster
                .intersect(s.viewpoint, d, 0.0, f32::INFINITY)
                .expect("closed behind");
            assert!(h.t > 0.1, "{d}: {}", h.t);
        }
        assert!(caster
            .intersect(s.viewpoint, -Vec3::Z, 0.0, f32::INFINITY)
            .is_none());
        // The tall block's top at 0.33 is seen from above.
        let top = caster
            .intersect(Vec3::new(0.37, 0.5, 0.35), -Vec3::Y, 0.0, f32::INFINITY)
            .expect("tall block");
        assert!((top.position.y - 0.33).abs() < 1e-6);
        // Face windings: room surfaces towards the room centre.
        let centre = Vec3::new(0.278, 0.2744, 0.2796);
        for t in 0..10 {
            let [a, b, c] = m.corners(t);
            assert!(
                (b - a).cross(c - a).dot(centre - a) > 0.0,
                "room triangle {t}"
            );
        }
        // scale parameter.
        let big = load_builtin("cornell?scale=1000").expect("loads");
        let (_, hi) = mesh_of(&big).bounds();
        assert!((hi.x - 556.0).abs() < 1e-3);
        assert_eq!(big.light.intensity, [0.5; 3]);
    }
}
