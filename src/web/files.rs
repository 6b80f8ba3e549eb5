//! Files in and out of the page: a download of bytes, and a file the user picks.

use std::cell::RefCell;
use std::rc::Rc;

use wasm_bindgen::JsCast;
use wasm_bindgen::prelude::*;

use crate::sketch::Sketch;

fn js(e: JsValue) -> String {
    format!("{e:?}")
}

/// Offers `sketch` as `sketch.png` in the format's palette.
pub fn download_sketch(sketch: &Sketch) -> Result<(), String> {
    let mut png = Vec::new();
    sketch.write_png(&mut png).map_err(|e| e.to_string())?;
    download("sketch.png", &png, "image/png")
}

/// Offers `bytes` as a file download named `name`.
pub fn download(name: &str, bytes: &[u8], mime: &str) -> Result<(), String> {
    let parts = js_sys::Array::of1(&js_sys::Uint8Array::from(bytes));
    let props = web_sys::BlobPropertyBag::new();
    props.set_type(mime);
    let blob = web_sys::Blob::new_with_u8_array_sequence_and_options(&parts, &props).map_err(js)?;
    let url = web_sys::Url::create_object_url_with_blob(&blob).map_err(js)?;
    let document = web_sys::window().and_then(|w| w.document()).ok_or("no document")?;
    let a: web_sys::HtmlAnchorElement = document.create_element("a").map_err(js)?.dyn_into().map_err(|_| "no anchor element")?;
    a.set_href(&url);
    a.set_download(name);
    a.click();
    // The download reads the blob after this returns: revoking the URL now can cancel it.
    let revoke = Closure::once_into_js(move || {
        let _ = web_sys::Url::revoke_object_url(&url);
    });
    web_sys::window().ok_or("no window")?.set_timeout_with_callback_and_timeout_and_arguments_0(revoke.unchecked_ref(), 60_000).map_err(js)?;
    Ok(())
}

/// Asks the user for a sketch PNG; the sketch (or why it is not one) lands in `slot`.
pub fn pick_sketch_file(slot: Rc<RefCell<Option<Result<Sketch, String>>>>) -> Result<(), String> {
    let document = web_sys::window().and_then(|w| w.document()).ok_or("no document")?;
    let input: web_sys::HtmlInputElement = document.create_element("input").map_err(js)?.dyn_into().map_err(|_| "no input element")?;
    input.set_type("file");
    input.set_accept("image/png");
    input.set_id("terrain_sketch_file");
    let _ = input.set_attribute("style", "display:none");
    document.body().ok_or("no body")?.append_child(&input).map_err(js)?;
    let el = input.clone();
    let on_change = Closure::<dyn FnMut()>::new(move || {
        let Some(file) = el.files().and_then(|f| f.get(0)) else { return };
        let (slot, el) = (slot.clone(), el.clone());
        wasm_bindgen_futures::spawn_local(async move {
            let result = match wasm_bindgen_futures::JsFuture::from(file.array_buffer()).await {
                Ok(buf) => Sketch::read_png(std::io::Cursor::new(js_sys::Uint8Array::new(&buf).to_vec())).map_err(|e| format!("{}: {e}", file.name())),
                Err(e) => Err(format!("{} could not be read: {e:?}", file.name())),
            };
            *slot.borrow_mut() = Some(result);
            el.remove();
        });
    });
    input.set_onchange(Some(on_change.as_ref().unchecked_ref()));
    on_change.forget();
    input.click();
    Ok(())
}

/// Downloads `url`'s body.
pub async fn fetch(url: &str) -> Result<Vec<u8>, String> {
    use wasm_bindgen_futures::JsFuture;
    let window = web_sys::window().ok_or("no window")?;
    let resp: web_sys::Response =
        JsFuture::from(window.fetch_with_str(url)).await.map_err(|e| format!("{url}: {e:?}"))?.dyn_into().map_err(|_| format!("{url}: not a response"))?;
    if !resp.ok() {
        return Err(format!("{url}: HTTP {}", resp.status()));
    }
    let buf = JsFuture::from(resp.array_buffer().map_err(|e| format!("{url}: {e:?}"))?).await.map_err(|e| format!("{url}: {e:?}"))?;
    Ok(js_sys::Uint8Array::new(&buf).to_vec())
}
