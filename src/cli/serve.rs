//! `lobe serve [FILES…] [--scene SCENE] [--port 8080] [--bind 127.0.0.1]`: the interactive page
//! ([`lobe::serve`]). Prints the address and serves until stopped.

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
}

pub fn run(a: &ServeArgs) -> Result<(), CliError> {
    let cfg = lobe::serve::Config {
        paths: a.files.clone(),
        scene: a.scene.clone(),
        bind: Some(a.bind),
        port: a.port,
        limits: lobe::serve::Limits::default(),
    };
    let server = lobe::serve::start(cfg).map_err(|e| match e {
        lobe::serve::StartError::Scene(d) => CliError::Diagnostics(d),
        lobe::serve::StartError::Other(m) => CliError::hint(m, "check the paths and that the port is free (--port 0 picks one)"),
    })?;
    println!("lobe serve: http://{}/", server.addr);
    if !a.bind.is_loopback() {
        eprintln!("warning: listening on {} — anyone who can reach this address can edit the served .brdf files", a.bind);
    }
    use std::io::Write;
    let _ = std::io::stdout().flush();
    server.wait();
    Ok(())
}
