//! The page and its script and style, compiled into the binary so `lobe serve` works offline and the page
//! always matches the server that sends it.

use super::http::Reply;

/// A page asset by name; unknown names are a 404-shaped reply.
pub(crate) fn asset(name: &str) -> Reply {
    let (ct, body): (&'static str, &'static str) = match name {
        "index.html" => ("text/html; charset=utf-8", include_str!("../../assets/serve/index.html")),
        "app.js" => ("text/javascript; charset=utf-8", include_str!("../../assets/serve/app.js")),
        "app.css" => ("text/css; charset=utf-8", include_str!("../../assets/serve/app.css")),
        _ => return super::http::ApiError::new(404, format!("no asset {name}")).reply(),
    };
    Reply::bytes(ct, body.as_bytes().to_vec())
}
