//! Files in and out of the page: a download of bytes, a file the user picks, a fetch.

use std::cell::RefCell;
use std::rc::Rc;

use wasm_bindgen::JsCast;
use wasm_bindgen::prelude::*;

use crate::ui::shell::{FileSlot, Picked, Refused};

fn js(e: JsValue) -> String {
    e.dyn_ref::<js_sys::Error>().map_or_else(|| format!("{e:?}"), |e| e.message().into())
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

thread_local! {
    /// The slot and size limit of the latest [`pick_file`] (the page has one file input; a
    /// page restarted after a lost device has a new slot).
    static SLOT: RefCell<Option<(FileSlot, f64)>> = const { RefCell::new(None) };
}

/// Asks the user for a file of type `accept`; it lands in `slot`, unread when it is larger
/// than `max_bytes`. The page has one hidden file input, made at the first call and reused (a
/// cancelled dialog leaves nothing behind).
pub fn pick_file(accept: &str, max_bytes: f64, slot: FileSlot) -> Result<(), String> {
    SLOT.with(|s| *s.borrow_mut() = Some((slot, max_bytes)));
    let document = web_sys::window().and_then(|w| w.document()).ok_or("no document")?;
    let input: web_sys::HtmlInputElement = match document.get_element_by_id("terrain_sketch_file") {
        Some(el) => el.dyn_into().map_err(|_| "#terrain_sketch_file is not an input")?,
        None => {
            let input: web_sys::HtmlInputElement = document.create_element("input").map_err(js)?.dyn_into().map_err(|_| "no input element")?;
            input.set_type("file");
            input.set_id("terrain_sketch_file");
            let _ = input.set_attribute("style", "display:none");
            document.body().ok_or("no body")?.append_child(&input).map_err(js)?;
            let el = input.clone();
            let on_change = Closure::<dyn FnMut()>::new(move || {
                let (Some(file), Some((slot, max_bytes))) = (el.files().and_then(|f| f.get(0)), SLOT.with(|s| s.borrow().clone())) else { return };
                if file.size() > max_bytes {
                    *slot.borrow_mut() = Some(Picked { name: file.name(), bytes: Err(Refused::TooBig(file.size())) });
                    return;
                }
                wasm_bindgen_futures::spawn_local(async move {
                    let bytes = wasm_bindgen_futures::JsFuture::from(file.array_buffer()).await;
                    let bytes = bytes.map(|b| js_sys::Uint8Array::new(&b).to_vec()).map_err(|e| Refused::Unreadable(js(e)));
                    *slot.borrow_mut() = Some(Picked { name: file.name(), bytes });
                });
            });
            input.set_onchange(Some(on_change.as_ref().unchecked_ref()));
            // The one input lives as long as the page, and so does its handler.
            on_change.forget();
            input
        }
    };
    input.set_accept(accept);
    // The same file chosen again is a change too.
    input.set_value("");
    input.click();
    Ok(())
}

/// Reads `file`, dropped on the page, onto `landed`: refused unread when its size is over
/// `max_bytes`.
pub fn read_dropped(file: egui::DroppedFileHandle, max_bytes: f64, landed: Rc<RefCell<Vec<Picked>>>) {
    let name = file.path().display().to_string();
    if let Some(size) = file.web_file().map(|f| f.size())
        && size > max_bytes
    {
        landed.borrow_mut().push(Picked { name, bytes: Err(Refused::TooBig(size)) });
        return;
    }
    wasm_bindgen_futures::spawn_local(async move {
        let bytes = file.bytes_async().await.map_err(Refused::Unreadable);
        landed.borrow_mut().push(Picked { name, bytes });
    });
}

/// Downloads `url`'s body.
pub async fn fetch(url: &str) -> Result<Vec<u8>, String> {
    use wasm_bindgen_futures::JsFuture;
    let window = web_sys::window().ok_or("no window")?;
    let resp: web_sys::Response =
        JsFuture::from(window.fetch_with_str(url)).await.map_err(|e| format!("{url}: {}", js(e)))?.dyn_into().map_err(|_| format!("{url}: not a response"))?;
    if !resp.ok() {
        return Err(format!("{url}: HTTP {}", resp.status()));
    }
    let buf = JsFuture::from(resp.array_buffer().map_err(|e| format!("{url}: {}", js(e)))?).await.map_err(|e| format!("{url}: {}", js(e)))?;
    Ok(js_sys::Uint8Array::new(&buf).to_vec())
}
