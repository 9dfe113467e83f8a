//! Copying textures back to the CPU (rows padded to wgpu's 256-byte alignment on the way).

use super::context::{Gpu, GpuError};
use crate::images::RgbImage;

/// Reads a whole 2-D texture of a 16-byte-per-texel format (`Rgba32Float`) as `4 * w * h`
/// floats, rows from the top.
pub fn read_rgba32f(gpu: &Gpu, texture: &wgpu::Texture) -> Result<Vec<f32>, GpuError> {
    let raw = read_raw(gpu, texture, 16)?;
    Ok(raw
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

/// Reads a whole `Rgba32Float` texture as an RGB image (alpha dropped).
pub fn read_rgb(gpu: &Gpu, texture: &wgpu::Texture) -> Result<RgbImage, GpuError> {
    let data = read_rgba32f(gpu, texture)?;
    Ok(RgbImage {
        width: texture.width(),
        height: texture.height(),
        pixels: data.chunks_exact(4).map(|c| [c[0], c[1], c[2]]).collect(),
    })
}

/// Reads a whole `Rgba16Float` texture as RGB triples in `f32`, rows from the top (copies
/// cannot convert formats, so the texels are converted here).
pub fn read_rgba16f_rgb(gpu: &Gpu, texture: &wgpu::Texture) -> Result<Vec<[f32; 3]>, GpuError> {
    let raw = read_raw(gpu, texture, 8)?;
    Ok(raw
        .chunks_exact(8)
        .map(|c| {
            let h = |k: usize| half::f16::from_le_bytes([c[2 * k], c[2 * k + 1]]).to_f32();
            [h(0), h(1), h(2)]
        })
        .collect())
}

/// Reads a whole 2-D texture of `bytes_per_texel` bytes per texel, rows from the top, without
/// the row padding.
pub fn read_raw(
    gpu: &Gpu,
    texture: &wgpu::Texture,
    bytes_per_texel: u32,
) -> Result<Vec<u8>, GpuError> {
    let (w, h) = (texture.width(), texture.height());
    let bytes_per_row = bytes_per_texel * w;
    let padded = bytes_per_row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
        * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let copy = |encoder: &mut wgpu::CommandEncoder, buffer: &wgpu::Buffer| {
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded),
                    rows_per_image: Some(h),
                },
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        )
    };
    staged(gpu, padded as u64 * h as u64, copy, |view| {
        let mut out = Vec::with_capacity((bytes_per_row * h) as usize);
        for row in 0..h as usize {
            let start = row * padded as usize;
            out.extend_from_slice(&view[start..start + bytes_per_row as usize]);
        }
        out
    })
}

/// Reads the first `count` values of a buffer created with `COPY_SRC` (floats, words,
/// resolved timestamp queries).
pub fn read_buffer<T: bytemuck::Pod>(
    gpu: &Gpu,
    buffer: &wgpu::Buffer,
    count: usize,
) -> Result<Vec<T>, GpuError> {
    let bytes = count * std::mem::size_of::<T>();
    let size = bytes.max(std::mem::size_of::<T>()) as u64;
    let copy = |encoder: &mut wgpu::CommandEncoder, staging: &wgpu::Buffer| {
        encoder.copy_buffer_to_buffer(buffer, 0, staging, 0, size)
    };
    staged(gpu, size, copy, |view| {
        bytemuck::pod_collect_to_vec::<u8, T>(&view[..bytes])
    })
}

/// [`read_buffer`] of floats.
pub fn read_buffer_f32(
    gpu: &Gpu,
    buffer: &wgpu::Buffer,
    count: usize,
) -> Result<Vec<f32>, GpuError> {
    read_buffer(gpu, buffer, count)
}

/// Copies into a staging buffer of `size` bytes with `copy`, waits for the copy and returns
/// what `read` makes of the buffer's bytes.
fn staged<T>(
    gpu: &Gpu,
    size: u64,
    copy: impl FnOnce(&mut wgpu::CommandEncoder, &wgpu::Buffer),
    read: impl FnOnce(&[u8]) -> T,
) -> Result<T, GpuError> {
    let staging = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut encoder = gpu
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("readback"),
        });
    copy(&mut encoder, &staging);
    gpu.queue.submit([encoder.finish()]);
    map_for_reading(gpu, &staging)?;
    let out = {
        let view = staging
            .get_mapped_range(..)
            .map_err(|e| GpuError::Readback(format!("{e:?}")))?;
        read(&view)
    };
    staging.unmap();
    Ok(out)
}

/// Maps a `MAP_READ` buffer after the submitted work that fills it, blocking until done.
fn map_for_reading(gpu: &Gpu, buffer: &wgpu::Buffer) -> Result<(), GpuError> {
    let (tx, rx) = std::sync::mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    gpu.wait()?;
    rx.recv()
        .map_err(|e| GpuError::Readback(e.to_string()))?
        .map_err(|e| GpuError::Readback(e.to_string()))
}
