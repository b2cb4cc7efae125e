//! TLS of the link (rustls through tonic, no OpenSSL).
//!
//! An `https://` endpoint is spoken to over TLS only: the coordinator's
//! certificate must chain to the configured CA (`[coordinator] ca_file`), and
//! with `cert_file` and `key_file` the agent presents its own certificate
//! (mutual TLS; the coordinator then takes the robot's identity from it).
//! There is no fallback: an `https://` endpoint without TLS settings, or TLS
//! settings with an `http://` endpoint, is an error before anything is sent,
//! so a bearer token never travels in the clear by mistake.

use std::path::Path;

use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, PrivateKeyDer};
use tonic::transport::{Certificate, ClientTlsConfig, Identity};

/// The link's TLS settings: PEM text already read and checked.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ClientTls {
    /// CA certificates that sign the coordinator's certificate (PEM).
    pub ca_pem: Vec<u8>,
    /// The robot's certificate chain and private key (PEM), for mutual TLS.
    pub identity: Option<(Vec<u8>, Vec<u8>)>,
    /// Name expected in the coordinator's certificate, when not the endpoint's host.
    pub domain: Option<String>,
}

/// A problem with one TLS file: the configuration key and the message (which names the file).
pub type FileError = (&'static str, String);

impl ClientTls {
    /// Reads and checks the PEM files; errors name the key and the file.
    pub fn from_files(
        ca_file: &Path,
        cert_file: Option<&Path>,
        key_file: Option<&Path>,
        domain: Option<String>,
    ) -> Result<Self, FileError> {
        let ca_pem = read_certificates(ca_file, "coordinator.ca_file")?;
        let identity = match (cert_file, key_file) {
            (Some(cert), Some(key)) => Some((
                read_certificates(cert, "coordinator.cert_file")?,
                read_key(key, "coordinator.key_file")?,
            )),
            (Some(_), None) => {
                return Err(("coordinator.key_file", "missing: cert_file needs its key".into()));
            }
            (None, Some(_)) => {
                return Err(("coordinator.cert_file", "missing: key_file needs its certificate".into()));
            }
            (None, None) => None,
        };
        Ok(ClientTls { ca_pem, identity, domain })
    }

    /// tonic's client settings.
    pub fn to_tonic(&self) -> ClientTlsConfig {
        let mut config = ClientTlsConfig::new().ca_certificate(Certificate::from_pem(&self.ca_pem));
        if let Some((cert, key)) = &self.identity {
            config = config.identity(Identity::from_pem(cert, key));
        }
        if let Some(domain) = &self.domain {
            config = config.domain_name(domain.clone());
        }
        config
    }
}

/// Checks that TLS settings and the endpoint's scheme agree: TLS exactly for `https://`.
pub fn check_scheme(endpoint: &str, tls: Option<&ClientTls>) -> Result<(), String> {
    let https = endpoint.starts_with("https://");
    match (https, tls.is_some()) {
        (true, false) => Err("an https:// endpoint needs TLS settings (coordinator.ca_file): \
                              refusing to connect without TLS"
            .into()),
        (false, true) => Err("TLS is configured (coordinator.ca_file) but the endpoint is not https://: \
                              refusing to connect without TLS"
            .into()),
        _ => Ok(()),
    }
}

fn read(file: &Path) -> Result<Vec<u8>, String> {
    std::fs::read(file).map_err(|e| format!("{}: cannot read: {e}", file.display()))
}

fn read_certificates(file: &Path, field: &'static str) -> Result<Vec<u8>, FileError> {
    let pem = read(file).map_err(|m| (field, m))?;
    let certs = CertificateDer::pem_slice_iter(&pem)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| (field, format!("{}: not valid PEM: {e}", file.display())))?;
    if certs.is_empty() {
        return Err((field, format!("{}: no \"BEGIN CERTIFICATE\" block in this file", file.display())));
    }
    Ok(pem)
}

fn read_key(file: &Path, field: &'static str) -> Result<Vec<u8>, FileError> {
    let pem = read(file).map_err(|m| (field, m))?;
    PrivateKeyDer::from_pem_slice(&pem).map_err(|e| {
        (field, format!("{}: no PEM private key (PKCS#8, PKCS#1 or SEC1) in this file: {e}", file.display()))
    })?;
    Ok(pem)
}
