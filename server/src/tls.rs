//! TLS for the coordinator's services (rustls through tonic, no OpenSSL),
//! and the names a client certificate gives its holder under mutual TLS.
//!
//! `[tls] cert` and `key` turn TLS on for every service on the listening
//! port (robot link, monitoring, health): clients must then connect with
//! `https://` and trust the CA that signed `cert`. With `client_ca` as well,
//! the handshake asks for a client certificate signed by that CA; one is not
//! required at the TLS level (an operator may still present a token), but a
//! certificate that is presented must verify, and it then identifies the
//! client (see [`peer_names`] and `service::auth`).
//!
//! The PEM files are read and parsed here, before the server starts (and by
//! `--check`): an error names the file, the configuration key and what is
//! wrong (unreadable, no certificate in it, no private key in it, a key that
//! does not belong to the certificate).

use std::path::Path;
use std::time::Duration;

use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, PrivateKeyDer};
use soundmap_proto::{Problem, ValidationError};
use tonic::transport::{Certificate, Identity, ServerTlsConfig};
use x509_parser::extensions::GeneralName;

use crate::config::TlsConfig;
use crate::error::ServerError;

/// A TLS handshake that takes longer than this is dropped.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// An error about the PEM file `file` configured at `field`.
fn pem_error(file: &Path, field: &str, message: impl Into<String>) -> ServerError {
    ServerError::Config {
        path: file.into(),
        error: ValidationError::new(field, Problem::Invalid(message.into())),
    }
}

fn read(file: &Path, field: &str) -> Result<Vec<u8>, ServerError> {
    std::fs::read(file).map_err(|e| pem_error(file, field, format!("cannot read: {e}")))
}

/// Reads the PEM certificates of `file` (at least one).
pub fn read_certificates(
    file: &Path,
    field: &str,
) -> Result<(Vec<u8>, Vec<CertificateDer<'static>>), ServerError> {
    let pem = read(file, field)?;
    let certs = CertificateDer::pem_slice_iter(&pem)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| pem_error(file, field, format!("not valid PEM: {e}")))?;
    if certs.is_empty() {
        return Err(pem_error(file, field, "no \"BEGIN CERTIFICATE\" block in this file"));
    }
    for (i, der) in certs.iter().enumerate() {
        x509_parser::parse_x509_certificate(der)
            .map_err(|e| pem_error(file, field, format!("certificate {} is not valid X.509: {e}", i + 1)))?;
    }
    Ok((pem, certs))
}

/// Reads the PEM private key of `file`.
pub fn read_private_key(file: &Path, field: &str) -> Result<(Vec<u8>, PrivateKeyDer<'static>), ServerError> {
    let pem = read(file, field)?;
    let key = PrivateKeyDer::from_pem_slice(&pem).map_err(|e| {
        pem_error(file, field, format!("no PEM private key (PKCS#8, PKCS#1 or SEC1) in this file: {e}"))
    })?;
    Ok((pem, key))
}

/// The server's TLS settings, `None` without `[tls] cert`. Every file is
/// read and parsed; the key is checked against the certificate.
pub fn server_config(tls: &TlsConfig) -> Result<Option<ServerTlsConfig>, ServerError> {
    let (Some(cert_file), Some(key_file)) = (&tls.cert, &tls.key) else {
        return Ok(None);
    };
    let (cert_pem, certs) = read_certificates(cert_file, "tls.cert")?;
    let (key_pem, key) = read_private_key(key_file, "tls.key")?;
    let signing = rustls_ring_key(&key).map_err(|e| pem_error(key_file, "tls.key", e))?;
    if let Some(public) = signing.public_key() {
        let (_, leaf) = x509_parser::parse_x509_certificate(&certs[0]).expect("parsed above");
        if leaf.public_key().raw != public.as_ref() {
            return Err(pem_error(
                key_file,
                "tls.key",
                format!("does not match tls.cert ({})", cert_file.display()),
            ));
        }
    }
    let mut config =
        ServerTlsConfig::new().identity(Identity::from_pem(cert_pem, key_pem)).timeout(HANDSHAKE_TIMEOUT);
    if let Some(ca_file) = &tls.client_ca {
        let (ca_pem, _) = read_certificates(ca_file, "tls.client_ca")?;
        config = config.client_ca_root(Certificate::from_pem(ca_pem)).client_auth_optional(true);
    }
    Ok(Some(config))
}

/// The key as rustls's ring provider loads it (what the TLS server will do).
fn rustls_ring_key(
    key: &PrivateKeyDer<'static>,
) -> Result<std::sync::Arc<dyn rustls::sign::SigningKey>, String> {
    rustls::crypto::ring::sign::any_supported_type(key).map_err(|e| format!("unusable private key: {e}"))
}

/// The names a certificate (DER) gives its holder: its DNS and URI subject
/// alternative names, then its subject's common names. Empty when it does not
/// parse (the TLS layer has verified it before this is asked).
pub fn peer_names(der: &[u8]) -> Vec<String> {
    let Ok((_, cert)) = x509_parser::parse_x509_certificate(der) else {
        return Vec::new();
    };
    let mut names = Vec::new();
    if let Ok(Some(san)) = cert.subject_alternative_name() {
        for name in &san.value.general_names {
            match name {
                GeneralName::DNSName(n) | GeneralName::URI(n) => names.push((*n).to_owned()),
                _ => {}
            }
        }
    }
    for cn in cert.subject().iter_common_name() {
        if let Ok(n) = cn.as_str() {
            names.push(n.to_owned());
        }
    }
    names
}
