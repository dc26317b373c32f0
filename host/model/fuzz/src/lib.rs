//! What the model's fuzz targets share: the files a fuzzed model names. The allocator that
//! checks the limits is `fuzz_support::LimitAlloc`.

pub use fuzz_support::LimitAlloc;

/// A 2×2 RGBA PNG: the texture of every image file a fuzzed model names.
pub fn small_png() -> Vec<u8> {
    let img = image::RgbaImage::from_pixel(2, 2, image::Rgba([200, 10, 10, 255]));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("PNG encoding in memory");
    out.into_inner()
}

/// The files a fuzzed model names: images are [`small_png`], an MTL library is `mtl`, the rest
/// are absent.
pub fn files(mtl: Option<&[u8]>) -> impl Fn(&std::path::Path) -> Result<Option<Vec<u8>>, model::ModelError> {
    let png = small_png();
    let mtl = mtl.map(<[u8]>::to_vec);
    move |path| {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        Ok(match ext.to_ascii_lowercase().as_str() {
            "png" | "jpg" | "jpeg" => Some(png.clone()),
            "mtl" => mtl.clone(),
            _ => None,
        })
    }
}
