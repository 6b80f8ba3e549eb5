//! Weight files and the kernels' layers: burn's convolutions and burnpack files to and from
//! [`Conv3`], float16 copies and averages of weight files.

use super::Conv3;

/// Copies a burn 3×3 convolution's weights and bias.
pub fn conv_from_burn(c: &burn::nn::conv::Conv2d) -> Result<Conv3, String> {
    let w = c.weight.val();
    let [cout, cin, _, _] = w.dims();
    let w: Vec<f32> = w.into_data().try_to_vec::<f32>().map_err(|e| format!("{e:?}"))?;
    let b: Option<Vec<f32>> = match &c.bias {
        Some(b) => Some(b.val().into_data().try_to_vec::<f32>().map_err(|e| format!("{e:?}"))?),
        None => None,
    };
    Conv3::from_oihw(cout, cin, &w, b.as_deref()).map_err(|e| e.to_string())
}

/// Writes `src`'s weights and bias into a burn 3×3 convolution of the same shape (the start of
/// a training run from weights the CPU kernels read); the parameters keep their
/// gradient-tracking state.
#[cfg(feature = "train")]
pub fn conv_into_burn(src: &Conv3, c: &mut burn::nn::conv::Conv2d) {
    use burn::tensor::{Tensor, TensorData};
    let (w, b) = src.to_oihw();
    let (cout, cin) = (src.cout, src.cin);
    c.weight = c.weight.clone().map(|t| {
        assert_eq!(t.dims(), [cout, cin, 3, 3], "conv_into_burn: shapes differ");
        let grad = t.is_require_grad();
        Tensor::<4>::from_data(TensorData::new(w, [cout, cin, 3, 3]), &t.device()).set_require_grad(grad)
    });
    if let Some(bias) = c.bias.take() {
        c.bias = Some(bias.map(|t| {
            let grad = t.is_require_grad();
            Tensor::<1>::from_data(TensorData::new(b, [cout]), &t.device()).set_require_grad(grad)
        }));
    }
}

/// Reads the 3×3 convolutions `layers` (name, output channels, input channels) from a
/// burnpack weight file (as burn writes it: `{name}.weight` [cout, cin, 3, 3] and
/// `{name}.bias` [cout], float32, or float16 as [`to_half_burnpack`] writes it) without a
/// tensor framework. Anything missing, misshapen or
/// non-finite is an error naming the tensor.
pub fn convs_from_burnpack(bytes: &[u8], layers: &[(String, usize, usize)]) -> Result<Vec<Conv3>, crate::models::WeightError> {
    let reader = burn_pack::Reader::from_bytes(burn_pack::Bytes::from_bytes_vec(bytes.to_vec())).map_err(|e| crate::models::WeightError::NotWeightFile(e.to_string()))?;
    let tensors = reader.into_tensors().map_err(|e| crate::models::WeightError::Unreadable(e.to_string()))?;
    let mut by_name = std::collections::HashMap::new();
    for t in tensors {
        let (name, dtype, shape, _, data) = t.into_parts().map_err(|e| crate::models::WeightError::Unreadable(e.to_string()))?;
        by_name.insert(name, (dtype, shape, data));
    }
    let mut get = |name: &str| -> Result<(Vec<usize>, Vec<f32>), crate::models::WeightError> {
        let (dtype, shape, data) = by_name.remove(name).ok_or_else(|| crate::models::WeightError::Missing(vec![name.to_string()]))?;
        let (size, decode): (usize, fn(&[u8]) -> f32) = match dtype {
            burn_pack::DType::F32 => (4, |c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
            burn_pack::DType::F16 => (2, |c| half::f16::from_le_bytes([c[0], c[1]]).to_f32()),
            _ => return Err(crate::models::WeightError::Type { name: name.to_string(), dtype: format!("{dtype:?}") }),
        };
        let dims = shape.to_vec();
        // A crafted shape may overflow: then no file can fill it.
        if dims.iter().try_fold(size, |n, &d| n.checked_mul(d)) != Some(data.len()) {
            return Err(crate::models::WeightError::Size { name: name.to_string(), bytes: data.len(), shape: dims });
        }
        let values = data.chunks_exact(size).map(decode).collect();
        Ok((dims, values))
    };
    let mut convs = Vec::new();
    for (name, cout, cin) in layers {
        let (cout, cin) = (*cout, *cin);
        let (wd, w) = get(&format!("{name}.weight"))?;
        if wd != [cout, cin, 3, 3] {
            return Err(crate::models::WeightError::Shape { name: format!("{name}.weight"), got: wd, want: vec![cout, cin, 3, 3] });
        }
        let (_, b) = get(&format!("{name}.bias"))?;
        convs.push(Conv3::from_oihw(cout, cin, &w, Some(&b)).map_err(|source| crate::models::WeightError::Layer { name: name.clone(), source })?);
    }
    Ok(convs)
}

/// Named 3×3 convolutions as a JSON object (`{name: {"shape": [cout, cin, 3, 3], "w": […],
/// "b": […]}}`, weights row-major in that shape), for reference runtimes that rebuild a
/// network (tools/tem_vs_onnx.py, tools/sketch_vs_onnx.py).
pub fn convs_json<'a>(named: impl IntoIterator<Item = (String, &'a Conv3)>) -> serde_json::Value {
    let m: serde_json::Map<String, serde_json::Value> = named
        .into_iter()
        .map(|(name, c)| {
            let (w, b) = c.to_oihw();
            (name, serde_json::json!({ "shape": [c.cout, c.cin, 3, 3], "w": w, "b": b }))
        })
        .collect();
    serde_json::Value::Object(m)
}

/// Writes the 3×3 convolutions `convs` under the names of `layers` as a burnpack weight file
/// (float32 `{name}.weight` [cout, cin, 3, 3] and `{name}.bias` [cout]), the inverse of
/// [`convs_from_burnpack`].
pub fn convs_to_burnpack(layers: &[(String, usize, usize)], convs: &[Conv3]) -> Vec<u8> {
    let le = |v: &[f32]| burn_pack::Bytes::from_bytes_vec(v.iter().flat_map(|x| x.to_le_bytes()).collect());
    let mut tensors = Vec::new();
    for ((name, _, _), c) in layers.iter().zip(convs) {
        let (w, b) = c.to_oihw();
        tensors.push(burn_pack::Tensor::new(format!("{name}.weight"), burn_pack::DType::F32, vec![c.cout, c.cin, 3, 3], None, le(&w)));
        tensors.push(burn_pack::Tensor::new(format!("{name}.bias"), burn_pack::DType::F32, vec![c.cout], None, le(&b)));
    }
    burn_pack::Writer::new(tensors).into_bytes().expect("an in-memory weight file").to_vec()
}

/// One tensor of a weight file: (name, dtype, shape, id, data).
type TensorParts = (String, burn_pack::DType, burn_pack::Shape, Option<u64>, burn_pack::Bytes);

/// The tensors of weight file `bytes` (burnpack), for the functions that rewrite weight files.
fn tensor_parts(bytes: &[u8]) -> Result<Vec<TensorParts>, String> {
    let reader = burn_pack::Reader::from_bytes(burn_pack::Bytes::from_bytes_vec(bytes.to_vec())).map_err(|e| format!("not a weight file ({e})"))?;
    reader.into_tensors().map_err(|e| format!("unreadable tensors ({e})"))?.into_iter().map(|t| t.into_parts().map_err(|e| format!("unreadable tensor ({e})"))).collect()
}

/// The weight file `bytes` (burnpack) with every float32 tensor stored as float16 (IEEE half,
/// rounded to nearest): half the download of every shipped network, whose outputs move by
/// about 1e-3 of their range. [`convs_from_burnpack`] reads it back to float32, and so does
/// burn with a float-cast adapter (the TEM on WebGPU). Other tensors are kept as they are.
pub fn to_half_burnpack(bytes: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    for (name, dtype, shape, id, data) in tensor_parts(bytes)? {
        let t = if dtype == burn_pack::DType::F32 {
            let half: Vec<u8> = data.chunks_exact(4).flat_map(|c| half::f16::from_f32(f32::from_le_bytes([c[0], c[1], c[2], c[3]])).to_le_bytes()).collect();
            burn_pack::Tensor::new(name, burn_pack::DType::F16, shape, id, burn_pack::Bytes::from_bytes_vec(half))
        } else {
            burn_pack::Tensor::new(name, dtype, shape, id, data)
        };
        out.push(t);
    }
    Ok(burn_pack::Writer::new(out).into_bytes().map_err(|e| format!("writing the weight file: {e}"))?.to_vec())
}

/// The element-wise mean of weight files (burnpack) of one network, e.g. the checkpoints at
/// the end of a training run (weight averaging: a smoother model than any one of them).
/// Every file must hold the same float32 tensors (names and shapes) in the same order.
pub fn average_burnpacks(files: &[Vec<u8>]) -> Result<Vec<u8>, String> {
    let Some((first, rest)) = files.split_first() else { return Err("no weight file to average".into()) };
    let mut sum: Vec<_> = tensor_parts(first)?
        .into_iter()
        .map(|(name, dtype, shape, id, data)| {
            if dtype != burn_pack::DType::F32 {
                return Err(format!("tensor {name} is {dtype:?}, not float32"));
            }
            let v: Vec<f64> = data.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f64).collect();
            Ok((name, shape, id, v))
        })
        .collect::<Result<_, _>>()?;
    for (k, file) in rest.iter().enumerate() {
        let tensors = tensor_parts(file)?;
        if tensors.len() != sum.len() {
            return Err(format!("file {} has {} tensors, the first {}", k + 2, tensors.len(), sum.len()));
        }
        for ((name, dtype, shape, _, data), (n0, s0, _, acc)) in tensors.into_iter().zip(sum.iter_mut()) {
            if name != *n0 || shape != *s0 || dtype != burn_pack::DType::F32 {
                return Err(format!("file {}: tensor {name} {shape:?} {dtype:?} does not match {n0} {s0:?} float32", k + 2));
            }
            for (a, c) in acc.iter_mut().zip(data.chunks_exact(4)) {
                *a += f32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f64;
            }
        }
    }
    let n = files.len() as f64;
    let out = sum
        .into_iter()
        .map(|(name, shape, id, acc)| {
            let bytes: Vec<u8> = acc.iter().flat_map(|v| ((v / n) as f32).to_le_bytes()).collect();
            burn_pack::Tensor::new(name, burn_pack::DType::F32, shape, id, burn_pack::Bytes::from_bytes_vec(bytes))
        })
        .collect();
    Ok(burn_pack::Writer::new(out).into_bytes().map_err(|e| format!("writing the weight file: {e}"))?.to_vec())
}
