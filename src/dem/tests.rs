//! Tests of the module.

use super::*;
use std::io::Cursor;

/// The shared data folder beside the repository (CI clones the repo with shared/ beside it).
fn shared(rel: &str) -> std::path::PathBuf {
    let p = crate::repo_root().join("..").join("shared").join(rel);
    assert!(p.exists(), "missing {}: the tests read ../shared", p.display());
    p
}

#[test]
fn dihedral_transforms_are_eight_distinct_symmetries_each_undone_by_its_inverse() {
    let src: Vec<f32> = (0..9).map(|k| k as f32).collect();
    let all: std::collections::HashSet<Vec<u32>> = (0..8).map(|t| dihedral(&src, 3, t).iter().map(|v| *v as u32).collect()).collect();
    assert_eq!(all.len(), 8);
    assert_eq!(dihedral(&src, 3, 0), src);
    assert_eq!(dihedral(&dihedral(&src, 3, 2), 3, 2), src, "two half-turns are the identity");
    for t in 0..8 {
        assert_eq!(dihedral(&dihedral(&src, 3, t), 3, dihedral_inverse(t)), src, "transform {t}");
    }
}

#[test]
fn tiff_round_trip_keeps_every_bit_the_spacing_and_no_data() {
    let mut data: Vec<f32> = (0..20).map(|k| k as f32 * 13.25 - 40.0).collect();
    data[7] = f32::NAN;
    let hf = Heightfield::new(5, 4, 32.0, data);
    let mut buf = Cursor::new(Vec::new());
    hf.write_tiff(&mut buf).unwrap();
    buf.set_position(0);
    let back = Heightfield::read_tiff(buf, 1.0).unwrap();
    assert_eq!((back.width, back.height, back.spacing_m), (5, 4, 32.0));
    assert!(hf.data.iter().zip(&back.data).all(|(a, b)| a.to_bits() == b.to_bits()));
}

#[test]
fn int16_tiff_with_a_nodata_value_reads_as_metres_and_nan() {
    let mut buf = Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let mut img = enc.new_image::<colortype::GrayI16>(3, 2).unwrap();
        img.encoder().write_tag(Tag::Unknown(GDAL_NODATA), "-32768").unwrap();
        img.write_data(&[100i16, -32768, 2500, -5, 0, 7]).unwrap();
    }
    buf.set_position(0);
    let hf = Heightfield::read_tiff(buf, 30.0).unwrap().validate().unwrap();
    assert_eq!(hf.spacing_m, 30.0);
    assert_eq!(hf.at(0, 0), 100.0);
    assert!(hf.at(1, 0).is_nan());
    assert_eq!(hf.at(0, 1), -5.0);
    assert!((hf.valid_fraction() - 5.0 / 6.0).abs() < 1e-9);
}

/// The shared DEMs read at their size, and exactly the samples equal to the file's GDAL
/// no-data value (read here with the tiff crate directly) become NaN.
#[test]
fn shared_dems_read_with_their_spacing_and_no_data() {
    let hf = Heightfield::read_path(&shared("dem/pypi_lidar_dem_1m.tif"), Some(1.0), PngScale::default()).unwrap();
    assert_eq!((hf.width, hf.height), (400, 400));
    let path = shared("dem/landlab_chiri_1m.tif");
    let chiri = Heightfield::read_path(&path, Some(1.0), PngScale::default()).unwrap();
    let mut dec = Decoder::new(std::fs::File::open(&path).unwrap()).unwrap();
    let nodata: f64 =
        dec.get_tag_ascii_string(Tag::Unknown(GDAL_NODATA)).ok().and_then(|s| s.trim_matches(|c: char| c.is_whitespace() || c == '\0').parse().ok()).unwrap_or(f64::NAN);
    let raw: Vec<f64> = match dec.read_image().unwrap() {
        DecodingResult::F32(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::F64(v) => v,
        other => panic!("unexpected sample type {:?}", std::mem::discriminant(&other)),
    };
    let missing = raw.iter().filter(|&&v| v as f32 == nodata as f32 || v.is_nan()).count();
    assert!(missing > 0 && missing < raw.len(), "the file has some no-data");
    assert_eq!(chiri.data.iter().filter(|v| v.is_nan()).count(), missing);
    assert!(chiri.data.iter().zip(&raw).all(|(a, b)| a.is_nan() || *a == *b as f32));
}

/// A GeoTIFF written with a georeference reads back with the same corner, EPSG code and
/// spacing; without one it is placed at (0, 0) in a user-defined metric frame.
#[test]
fn geotiff_tiepoint_and_crs_round_trip() {
    let geo = GeoRef { origin_m: [500_000.5, 4_649_776.25], epsg: Some(32632) };
    let hf = Heightfield::new(3, 2, 25.0, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]).with_geo(Some(geo));
    let mut buf = Cursor::new(Vec::new());
    hf.write_tiff(&mut buf).unwrap();
    buf.set_position(0);
    let back = Heightfield::read_tiff(buf, f64::NAN).unwrap();
    assert_eq!((back.spacing_m, back.geo), (25.0, Some(geo)));
    let mut buf = Cursor::new(Vec::new());
    Heightfield::new(1, 1, 2.0, vec![9.0]).write_tiff(&mut buf).unwrap();
    buf.set_position(0);
    assert_eq!(Heightfield::read_tiff(buf, f64::NAN).unwrap().geo, Some(GeoRef { origin_m: [0.0, 0.0], epsg: None }));
}

/// Writes a geographic (degree) GeoTIFF of `w × h` with pixel size `sx° × sy°`, north-west
/// corner at (`lon`, `lat`).
fn degree_tiff(w: u32, h: u32, sx: f64, sy: f64, lon: f64, lat: f64) -> Cursor<Vec<u8>> {
    let mut buf = Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let mut img = enc.new_image::<colortype::Gray32Float>(w, h).unwrap();
        img.encoder().write_tag(Tag::Unknown(MODEL_PIXEL_SCALE), &[sx, sy, 0.0][..]).unwrap();
        img.encoder().write_tag(Tag::Unknown(MODEL_TIEPOINT), &[0.0, 0.0, 0.0, lon, lat, 0.0][..]).unwrap();
        img.encoder().write_tag(Tag::Unknown(GEO_KEY_DIRECTORY), &[1u16, 1, 0, 2, geokey::MODEL_TYPE, 0, 1, 2, 2048, 0, 1, 4326][..]).unwrap();
        img.write_data(&vec![100f32; (w * h) as usize]).unwrap();
    }
    buf.set_position(0);
    buf
}

/// Degree pixels are converted to metres at the grid's latitude (1″ × 1″ near the
/// equator ≈ 30.8 m); where a degree pixel is far from square (1″ at 46° N is 21.5 m ×
/// 30.9 m) the reader refuses and says why, instead of taking degrees for metres.
#[test]
fn degree_pixels_are_converted_or_refused() {
    let arcsec = 1.0 / 3600.0;
    let hf = Heightfield::read_tiff(degree_tiff(4, 4, arcsec, arcsec, 10.0, 0.5), f64::NAN).unwrap();
    let (lon_m, lat_m) = metres_per_degree(0.5 - 2.0 * arcsec);
    assert!((hf.spacing_m - 0.5 * (lon_m + lat_m) * arcsec).abs() < 1e-9 && (30.7..30.95).contains(&hf.spacing_m), "{}", hf.spacing_m);
    assert_eq!(hf.geo, None, "degrees are not a projected frame");
    let e = Heightfield::read_tiff(degree_tiff(4, 4, arcsec, arcsec, 7.0, 46.0), f64::NAN).unwrap_err().to_string();
    assert!(e.contains("21.5 m × 30.9 m") && e.contains("reproject"), "{e}");
    // 1.44″ × 1″ at 46° N is square in metres again.
    let ok = Heightfield::read_tiff(degree_tiff(4, 4, 1.44 * arcsec, arcsec, 7.0, 46.0), f64::NAN).unwrap();
    assert!((30.5..31.2).contains(&ok.spacing_m), "{}", ok.spacing_m);
    // One degree per metre at the equator: 111 km per degree, never 1 m.
    let (lon, lat) = metres_per_degree(0.0);
    assert!((lon - 111_319.5).abs() < 1.0 && (lat - 110_574.3).abs() < 1.0, "{lon} {lat}");
}

/// The terrain-RGB fixture (Mount Fuji) decodes to its exact highest sample, 3,751.0 m (the
/// summit is 3,776 m; the tile's pixels average over tens of metres), and a far lower foot.
#[test]
fn terrain_rgb_fixture_decodes_to_its_exact_summit() {
    let hf = Heightfield::read_path(&shared("fixtures/fuji_terrain_rgb.png"), Some(30.0), PngScale::default()).unwrap();
    let max = hf.data.iter().copied().filter(|v| !v.is_nan()).fold(f32::MIN, f32::max);
    let min = hf.data.iter().copied().filter(|v| !v.is_nan()).fold(f32::MAX, f32::min);
    assert!((max - 3751.0).abs() < 0.05, "the fixture's highest sample is 3751.0 m, read {max}");
    assert!(min < 1500.0, "the foot is far lower: {min}");
}

/// A projected GeoTIFF in US survey feet (EPSG linear unit 9003) or international feet (9002)
/// with 100-unit pixels reads as 30.48006 m or 30.48 m pixels.
#[test]
fn feet_pixels_are_read_in_metres() {
    for (unit, metres) in [(9002u16, 30.48), (9003, 30.480_060_960_121_92)] {
        let mut buf = Cursor::new(Vec::new());
        {
            let mut enc = TiffEncoder::new(&mut buf).unwrap();
            let mut img = enc.new_image::<colortype::Gray32Float>(2, 2).unwrap();
            img.encoder().write_tag(Tag::Unknown(MODEL_PIXEL_SCALE), &[100.0, 100.0, 0.0][..]).unwrap();
            img.encoder().write_tag(Tag::Unknown(MODEL_TIEPOINT), &[0.0, 0.0, 0.0, 1000.0, 2000.0, 0.0][..]).unwrap();
            img.encoder().write_tag(Tag::Unknown(GEO_KEY_DIRECTORY), &[1u16, 1, 0, 2, geokey::MODEL_TYPE, 0, 1, 1, geokey::LINEAR_UNITS, 0, 1, unit][..]).unwrap();
            img.write_data(&[1f32, 2.0, 3.0, 4.0]).unwrap();
        }
        buf.set_position(0);
        let hf = Heightfield::read_tiff(buf, f64::NAN).unwrap();
        assert!((hf.spacing_m - metres).abs() < 1e-9, "unit {unit}: {} m", hf.spacing_m);
        assert_eq!(hf.geo.unwrap().origin_m, [1000.0 * metres / 100.0, 2000.0 * metres / 100.0]);
    }
}

#[test]
fn png16_heightmaps_apply_the_scale() {
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, 2, 1);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let mut wr = enc.write_header().unwrap();
        wr.write_image_data(&[0x01, 0x00, 0xFF, 0xFF]).unwrap();
    }
    let hf = Heightfield::read_png(Cursor::new(bytes), PngScale { metres_per_unit: 0.1, offset_m: -100.0 }, 5.0).unwrap();
    assert_eq!(hf.data, vec![256.0 * 0.1 - 100.0, 65535.0 * 0.1 - 100.0]);
}

#[test]
fn corrupt_or_absurd_files_are_clear_errors() {
    let err = Heightfield::read_tiff(Cursor::new(b"II*\0garbage".to_vec()), 1.0).unwrap_err();
    assert!(matches!(err, DemError::Format(_)), "{err}");
    assert!(Heightfield::read_png(Cursor::new(b"\x89PNG\r\n\x1a\nxx".to_vec()), PngScale::default(), 1.0).is_err());
    let absurd = Heightfield::new(2, 1, 1.0, vec![0.0, 1.0e6]).validate().unwrap_err();
    assert!(absurd.to_string().contains("not terrain"), "{absurd}");
    let empty = Heightfield::new(1, 1, 1.0, vec![f32::NAN]).validate().unwrap_err();
    assert!(empty.to_string().contains("no-data"));
    let p = std::env::temp_dir().join("terrain-not-a-dem.xyz");
    std::fs::write(&p, b"x").unwrap();
    assert!(Heightfield::read_path(&p, Some(1.0), PngScale::default()).unwrap_err().to_string().contains("extension"));
}

#[test]
fn area_resampling_preserves_means_and_refuses_to_upsample() {
    let hf = Heightfield::new(4, 4, 1.0, (0..16).map(|k| k as f32).collect());
    let d = hf.downsample2();
    assert_eq!(d.data, vec![2.5, 4.5, 10.5, 12.5]);
    assert_eq!(d.spacing_m, 2.0);
    let r = hf.resample_area(2.0).unwrap();
    assert_eq!(r.data, d.data);
    let big = Heightfield::new(10, 10, 20.0, (0..100).map(|k| (k % 10) as f32 * 3.0).collect());
    let r = big.resample_area(32.0).unwrap();
    assert_eq!((r.width, r.height), (6, 6));
    // A linear ramp stays a ramp: the first output covers input x ∈ [0, 1.6) → mean x 0.8·… .
    let expected0 = (1.0 * 0.0 + 0.6 * 3.0) / 1.6;
    assert!((r.at(0, 0) as f64 - expected0).abs() < 1e-4, "{}", r.at(0, 0));
    assert!(big.resample_area(10.0).is_err());
    let nan = Heightfield::new(2, 2, 1.0, vec![1.0, f32::NAN, 1.0, 1.0]).downsample2();
    assert!(nan.data[0].is_nan());
}

#[test]
fn bicubic_upsampling_follows_smooth_surfaces() {
    // Keys' kernel with a = −0.75 (as PyTorch's bicubic) keeps constants exactly and
    // follows a ramp to within 5 % of its slope per coarse sample.
    let hf = Heightfield::new(8, 8, 2.0, (0..64).map(|k| (k % 8) as f32 * 4.0 + (k / 8) as f32).collect());
    let up = hf.upsample_bicubic2();
    assert_eq!((up.width, up.height, up.spacing_m), (16, 16, 1.0));
    for y in 4..12 {
        for x in 4..12 {
            let want = (x as f32 * 0.5 - 0.25) * 4.0 + (y as f32 * 0.5 - 0.25);
            assert!((up.at(x, y) - want).abs() < 0.05 * 5.0, "({x},{y}) {} vs {want}", up.at(x, y));
        }
    }
    let flat = Heightfield::new(4, 4, 1.0, vec![123.5; 16]).upsample_bicubic2();
    assert!(flat.data.iter().all(|&v| (v - 123.5).abs() < 1e-4));
    let w: f32 = cubic_weights(0.3).iter().sum();
    assert!((w - 1.0).abs() < 1e-6);
}

/// A DEM a user gives: the GeoTIFF's own 25 m is used without a spacing and with a
/// matching one; a conflicting 30 m is refused with both numbers; a file without a pixel
/// size needs one (refused without, read with it).
#[test]
fn a_user_spacing_must_agree_with_the_files_own() {
    let dir = std::env::temp_dir().join(format!("terrain-user-spacing-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let tif = dir.join("own.tif");
    Heightfield::new(2, 2, 25.0, vec![1.0, 2.0, 3.0, 4.0]).write_tiff(std::fs::File::create(&tif).unwrap()).unwrap();
    let read = |path: &std::path::Path, given| Heightfield::read_user_path(path, given, PngScale::default());
    assert_eq!(read(&tif, None).unwrap().spacing_m, 25.0);
    assert_eq!(read(&tif, Some(25.1)).unwrap().spacing_m, 25.0, "within 1 %");
    let e = read(&tif, Some(30.0)).unwrap_err().to_string();
    assert!(e.contains("says its pixels are 25 m, but 30 m was given"), "{e}");
    let plain = dir.join("plain.tif");
    {
        let mut enc = TiffEncoder::new(std::fs::File::create(&plain).unwrap()).unwrap();
        enc.write_image::<colortype::Gray32Float>(2, 2, &[1.0, 2.0, 3.0, 4.0]).unwrap();
    }
    assert!(read(&plain, None).unwrap_err().to_string().contains("has no pixel size"));
    assert_eq!(read(&plain, Some(8.0)).unwrap().spacing_m, 8.0);
}

/// A projected GeoTIFF with pixels 10 m × 12 m is refused (heightfields are square), instead
/// of being read as 10 m in both directions.
#[test]
fn non_square_projected_pixels_are_refused() {
    let mut buf = Cursor::new(Vec::new());
    {
        let mut enc = TiffEncoder::new(&mut buf).unwrap();
        let mut img = enc.new_image::<colortype::Gray32Float>(2, 2).unwrap();
        img.encoder().write_tag(Tag::Unknown(MODEL_PIXEL_SCALE), &[10.0, 12.0, 0.0][..]).unwrap();
        img.encoder().write_tag(Tag::Unknown(MODEL_TIEPOINT), &[0.0, 0.0, 0.0, 500_000.0, 5_000_000.0, 0.0][..]).unwrap();
        img.encoder().write_tag(Tag::Unknown(GEO_KEY_DIRECTORY), &[1u16, 1, 0, 1, geokey::MODEL_TYPE, 0, 1, 1][..]).unwrap();
        img.write_data(&[1f32, 2.0, 3.0, 4.0]).unwrap();
    }
    buf.set_position(0);
    let e = Heightfield::read_tiff(buf, f64::NAN).unwrap_err().to_string();
    assert!(e.contains("10 × 12") && e.contains("square pixels"), "{e}");
}

/// No-data filling gives every NaN sample the value of its nearest valid sample (4-neighbour
/// steps; ties to the first in row order), the same as a search started from every valid
/// sample (the reference here), on a grid with holes of all shapes and at the borders; a grid
/// without no-data comes back unchanged, one with nothing but no-data is `None`.
#[test]
fn no_data_takes_the_nearest_valid_sample() {
    let (w, h) = (37, 23);
    let data: Vec<f32> = (0..w * h).map(|k| if (k * 7919 % 13 < 6) || (k % w > 20 && k / w < 9) || k % w == 0 { f32::NAN } else { k as f32 }).collect();
    let hf = Heightfield::new(w, h, 5.0, data.clone());
    let mut want = data.clone();
    let mut queue: std::collections::VecDeque<usize> = (0..w * h).filter(|&i| !data[i].is_nan()).collect();
    while let Some(i) = queue.pop_front() {
        let (x, y) = (i % w, i / w);
        for (ok, j) in [(x > 0, i.wrapping_sub(1)), (x + 1 < w, i + 1), (y > 0, i.wrapping_sub(w)), (y + 1 < h, i + w)] {
            if ok && want[j].is_nan() {
                want[j] = want[i];
                queue.push_back(j);
            }
        }
    }
    let got = hf.fill_nodata().unwrap();
    assert!(data.iter().filter(|v| v.is_nan()).count() > 200);
    assert_eq!(got.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), want.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
    let full = Heightfield::new(w, h, 5.0, (0..w * h).map(|k| k as f32).collect());
    assert_eq!(full.fill_nodata().unwrap().data, full.data);
    assert!(Heightfield::new(w, h, 5.0, vec![f32::NAN; w * h]).fill_nodata().is_none());
}
