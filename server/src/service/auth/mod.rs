//! Who a call comes from and what it may do.
//!
//! # Principals and roles
//!
//! | principal | credential | may call |
//! |---|---|---|
//! | robot `R` | `[auth.tokens] R = TOKEN`, or a client certificate naming `R` | `RobotLink.Connect` with `hello.robot_id = R` |
//! | operator, role `read` | `[auth.operators.NAME]` token, or a certificate naming `NAME` | `GetState`, `WatchEstimates` |
//! | operator, role `control` | the same | also `SetActivePositioning`, `SetFocus` |
//! | anonymous | none | everything, only while **no** credential is configured |
//!
//! A token travels as `authorization: Bearer TOKEN` metadata; a certificate
//! is the client certificate of a mutual-TLS connection (`[tls] client_ca`),
//! whose DNS/URI subject alternative names and subject common name are the
//! names it gives (see [`crate::tls::peer_names`]). A certificate naming an
//! operator is that operator; any other certificate is a robot's, good for
//! the robot ids it names.
//!
//! As soon as one credential exists (a robot token, an operator, a client
//! CA), nothing is anonymous: a call without a credential is
//! `UNAUTHENTICATED` on every service but health, whatever `[auth] required`
//! says. So a robot id with a token can only be used with that token. A
//! credential that is not known is `UNAUTHENTICATED`; a known credential
//! used beyond its rights (a robot calling `Monitoring`, a `read` operator
//! calling `SetFocus`, a hello for another robot id, a token and a
//! certificate of different principals) is `PERMISSION_DENIED`.
//!
//! Tokens are compared in constant time ([`subtle`]) against every configured
//! token, so the time of a refusal does not tell how much of a guess was right.

#[cfg(test)]
mod tests;

use soundmap_proto::RobotId;
use subtle::ConstantTimeEq;
use tonic::Request;
use tonic::metadata::MetadataMap;

use crate::config::{AuthConfig, Role, TlsConfig};
use crate::error::ServerError;

/// Who a call comes from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Principal {
    /// A robot proven by its token.
    Robot(RobotId),
    /// A client certificate that names no operator: a robot, for the ids it names.
    RobotCertificate(Vec<String>),
    /// An operator.
    Operator {
        /// Its configured name.
        name: String,
        /// What it may do.
        role: Role,
    },
}

impl Principal {
    fn describe(&self) -> String {
        match self {
            Principal::Robot(id) => format!("robot {id}"),
            Principal::RobotCertificate(names) => format!("robot certificate for {}", names.join(", ")),
            Principal::Operator { name, role } => format!("operator {name} (role {role:?})"),
        }
    }

    fn names(&self) -> Vec<&str> {
        match self {
            Principal::Robot(id) => vec![id.as_str()],
            Principal::RobotCertificate(names) => names.iter().map(String::as_str).collect(),
            Principal::Operator { name, .. } => vec![name.as_str()],
        }
    }
}

/// Resolves credentials to principals and checks what they may do.
#[derive(Clone, Debug, Default)]
pub struct Authenticator {
    /// Whether any credential is configured: then no call is anonymous.
    closed: bool,
    tokens: Vec<(Vec<u8>, Principal)>,
    operators: Vec<(String, Role)>,
}

impl Authenticator {
    /// From validated configuration.
    pub fn new(auth: &AuthConfig, tls: &TlsConfig) -> Self {
        let mut tokens = Vec::new();
        for (id, token) in &auth.tokens {
            if let Ok(id) = RobotId::parse(id, "auth.tokens") {
                tokens.push((token.as_bytes().to_vec(), Principal::Robot(id)));
            }
        }
        let mut operators = Vec::new();
        for (name, op) in &auth.operators {
            if let Some(token) = &op.token {
                tokens.push((
                    token.as_bytes().to_vec(),
                    Principal::Operator { name: name.clone(), role: op.role },
                ));
            }
            operators.push((name.clone(), op.role));
        }
        Authenticator { closed: auth.is_closed(tls), tokens, operators }
    }

    /// Whether calls need a credential.
    pub fn is_closed(&self) -> bool {
        self.closed
    }

    /// The principal a request's credentials prove: its bearer token and its
    /// client certificate (names taken from the leaf). `None` only when no
    /// credential is configured and the request carries none.
    pub fn identify<T>(&self, request: &Request<T>) -> Result<Option<Principal>, ServerError> {
        let names = request
            .peer_certs()
            .and_then(|chain| chain.first().map(|leaf| crate::tls::peer_names(leaf)))
            .filter(|names| !names.is_empty());
        self.identify_parts(request.metadata(), names)
    }

    /// [`identify`](Self::identify) from the metadata and the client
    /// certificate's names.
    pub fn identify_parts(
        &self,
        metadata: &MetadataMap,
        cert_names: Option<Vec<String>>,
    ) -> Result<Option<Principal>, ServerError> {
        let by_token = match metadata.get("authorization") {
            Some(value) => Some(self.by_token(value.as_bytes())?),
            None => None,
        };
        let by_cert = cert_names.map(|names| self.by_certificate(names));
        match (by_token, by_cert) {
            (Some(t), Some(c)) => {
                // Both must be the same principal: the token's name is among the certificate's.
                let cert_names = c.names();
                if t.names().iter().all(|n| !cert_names.contains(n)) {
                    return Err(ServerError::PermissionDenied(format!(
                        "authorization: the token is for {} but the client certificate is a {}",
                        t.describe(),
                        c.describe()
                    )));
                }
                Ok(Some(t))
            }
            (Some(p), None) | (None, Some(p)) => Ok(Some(p)),
            (None, None) if self.closed => Err(ServerError::Unauthenticated(
                "authorization: missing (expected \"Bearer TOKEN\" or a client certificate)".into(),
            )),
            (None, None) => Ok(None),
        }
    }

    fn by_token(&self, header: &[u8]) -> Result<Principal, ServerError> {
        let token = header
            .strip_prefix(b"Bearer ")
            .map(|t| t.trim_ascii())
            .ok_or_else(|| ServerError::Unauthenticated("authorization: expected \"Bearer TOKEN\"".into()))?;
        // Every configured token is compared (in constant time each), whichever matches.
        let mut found = None;
        for (known, principal) in &self.tokens {
            if bool::from(known.as_slice().ct_eq(token)) {
                found = Some(principal);
            }
        }
        found.cloned().ok_or_else(|| ServerError::Unauthenticated("authorization: unknown token".into()))
    }

    fn by_certificate(&self, names: Vec<String>) -> Principal {
        for (name, role) in &self.operators {
            if names.iter().any(|n| n == name) {
                return Principal::Operator { name: name.clone(), role: *role };
            }
        }
        Principal::RobotCertificate(names)
    }

    /// May `who` say hello as `robot_id`? The authenticated robot id when
    /// the call carried a credential.
    pub fn authorize_robot(
        &self,
        who: Option<&Principal>,
        robot_id: &RobotId,
    ) -> Result<Option<RobotId>, ServerError> {
        match who {
            None if self.closed => Err(ServerError::Unauthenticated("authorization: missing".into())),
            None => Ok(None),
            Some(Principal::Robot(id)) if id == robot_id => Ok(Some(id.clone())),
            Some(Principal::Robot(id)) => {
                Err(ServerError::IdentityMismatch { claimed: robot_id.clone(), authenticated: id.clone() })
            }
            Some(Principal::RobotCertificate(names)) if names.iter().any(|n| n == robot_id.as_str()) => {
                Ok(Some(robot_id.clone()))
            }
            Some(p @ Principal::RobotCertificate(_)) => Err(ServerError::PermissionDenied(format!(
                "hello.robot_id: {robot_id} is not named by the client certificate ({})",
                p.describe()
            ))),
            Some(p @ Principal::Operator { .. }) => {
                Err(ServerError::PermissionDenied(format!("{} may not connect as a robot", p.describe())))
            }
        }
    }

    /// May a plain HTTP request with this `Authorization` header value (the
    /// metrics endpoint) do what needs `role`? Tokens only (the endpoint has no
    /// TLS); anonymous only when no credential is configured.
    pub fn authorize_http(&self, authorization: Option<&[u8]>, role: Role) -> Result<(), ServerError> {
        let who = match authorization {
            Some(value) => Some(self.by_token(value)?),
            None if self.closed => {
                return Err(ServerError::Unauthenticated(
                    "authorization: missing (expected \"Bearer TOKEN\" of an operator)".into(),
                ));
            }
            None => None,
        };
        self.operator_may(who, role)
    }

    /// May the call's credentials do what needs `role`?
    pub fn authorize_operator<T>(&self, request: &Request<T>, role: Role) -> Result<(), ServerError> {
        self.operator_may(self.identify(request)?, role)
    }

    fn operator_may(&self, who: Option<Principal>, role: Role) -> Result<(), ServerError> {
        match who {
            None => Ok(()),
            Some(Principal::Operator { role: has, .. }) if has >= role => Ok(()),
            Some(p) => Err(ServerError::PermissionDenied(format!(
                "{} may not call this: it needs an operator with role {}",
                p.describe(),
                match role {
                    Role::Read => "read or control",
                    Role::Control => "control",
                }
            ))),
        }
    }
}
