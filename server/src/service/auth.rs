//! Who a connection is: bearer tokens mapped to robot ids.

use std::collections::HashMap;

use soundmap_proto::RobotId;
use tonic::metadata::MetadataMap;

use crate::config::AuthConfig;
use crate::error::ServerError;

/// Resolves credentials to robot identities.
#[derive(Clone, Debug, Default)]
pub struct Authenticator {
    required: bool,
    by_token: HashMap<String, RobotId>,
}

impl Authenticator {
    /// From validated configuration.
    pub fn new(config: &AuthConfig) -> Self {
        let by_token = config
            .tokens
            .iter()
            .filter_map(|(id, token)| Some((token.clone(), RobotId::parse(id, "auth.tokens").ok()?)))
            .collect();
        Authenticator { required: config.required, by_token }
    }

    /// The identity the request's `authorization: Bearer TOKEN` proves, `None`
    /// when it carries none and none is required.
    pub fn identify(&self, metadata: &MetadataMap) -> Result<Option<RobotId>, ServerError> {
        let Some(value) = metadata.get("authorization") else {
            return if self.required {
                Err(ServerError::Unauthenticated("authorization: missing (expected \"Bearer TOKEN\")".into()))
            } else {
                Ok(None)
            };
        };
        let token =
            value.to_str().ok().and_then(|v| v.strip_prefix("Bearer ")).ok_or_else(|| {
                ServerError::Unauthenticated("authorization: expected \"Bearer TOKEN\"".into())
            })?;
        match self.by_token.get(token.trim()) {
            Some(id) => Ok(Some(id.clone())),
            None => Err(ServerError::Unauthenticated("authorization: unknown token".into())),
        }
    }
}
