//! `lobe serve [FILES…] [--scene SCENE] [--port 8080] [--bind 127.0.0.1] [--deadline 10]`: the interactive page
//! ([`lobe::serve`]). Prints the address and serves until stopped.

use super::args::Json;
use super::common::CliError;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    /// Formula files or directories to serve (their directories are the only ones the page may read or
    /// write; default: the current directory). The first file opens in the editor.
    pub files: Vec<PathBuf>,
    /// Scene the page renders (default: the papers' sphere, built in).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// TCP port (0 picks a free one).
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Address to listen on; loopback unless you say otherwise (the page can save files).
    #[arg(long, default_value = "127.0.0.1")]
    pub bind: std::net::IpAddr,
    /// Seconds a computation (a render, an analysis) may run before it is stopped and answered 503.
    #[arg(long, default_value_t = 10.0, value_parser = positive_seconds)]
    pub deadline: f64,
    /// Print the address as one JSON line (`url`, `address`, `port`, `loopback`) once the server listens.
    #[command(flatten)]
    pub json: Json,
}

fn positive_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v <= 86_400.0 => Ok(v),
        _ => Err(format!("`{s}` is not a number of seconds in (0, 86400]")),
    }
}

pub fn run(a: &ServeArgs) -> Result<(), CliError> {
    let cfg = lobe::serve::Config {
        paths: a.files.clone(),
        scene: a.scene.clone(),
        bind: Some(a.bind),
        port: a.port,
        limits: lobe::serve::Limits { deadline: std::time::Duration::from_secs_f64(a.deadline), ..Default::default() },
    };
    let server = lobe::serve::start(cfg).map_err(|e| match e {
        lobe::serve::StartError::Scene(d) => CliError::Diagnostics(d),
        lobe::serve::StartError::Other(m) => CliError::hint(m, "check the paths and that the port is free (--port 0 picks one)"),
    })?;
    if a.json.on {
        let j = serde_json::json!({"url": format!("http://{}/", server.addr), "address": server.addr.ip().to_string(), "port": server.addr.port(), "loopback": a.bind.is_loopback()});
        println!("{j}");
    } else {
        println!("lobe serve: http://{}/", server.addr);
    }
    if !a.bind.is_loopback() {
        eprintln!("warning: listening on {} — anyone who can reach this address can edit the served .brdf files", a.bind);
    }
    use std::io::Write;
    let _ = std::io::stdout().flush();
    server.wait();
    Ok(())
}
