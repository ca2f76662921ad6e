//! Who may do what over OPC UA: anonymous sessions browse, read and subscribe when the
//! configuration allows it; only a configured user may call a method (every method of the
//! vision system changes something: the state, a job, a trigger).

use async_opcua::crypto::SecurityPolicy;
use async_opcua::server::authenticator::{AuthManager, Password, UserToken, user_pass_security_policy_id};
use async_opcua::server::{ANONYMOUS_USER_TOKEN_ID, ServerEndpoint};
use async_opcua::types::{Error, NodeId, StatusCode, UAString, UserTokenPolicy, UserTokenType};

use crate::config::OpcuaUser;

/// The policy id of anonymous tokens (the server's own constant, which it checks tokens against).
const ANONYMOUS_POLICY: &str = "anonymous";

/// The configured users, checked in constant time per user.
pub struct Users {
    users: Vec<OpcuaUser>,
    anonymous: bool,
}

impl Users {
    /// Users from `[[opcua.users]]`; `anonymous`: `allow_anonymous_read`.
    pub fn new(users: Vec<OpcuaUser>, anonymous: bool) -> Self {
        Self { users, anonymous }
    }
}

/// Equal bytes, compared without stopping at the first difference.
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

#[async_trait::async_trait]
impl AuthManager for Users {
    async fn authenticate_anonymous_token(&self, endpoint: &ServerEndpoint) -> Result<(), Error> {
        if self.anonymous {
            Ok(())
        } else {
            tracing::warn!("OPC UA: anonymous session refused on {} ([opcua] allow_anonymous_read = false)", endpoint.path);
            Err(Error::new(StatusCode::BadIdentityTokenRejected, "anonymous sessions are not allowed"))
        }
    }

    async fn authenticate_username_identity_token(
        &self,
        _endpoint: &ServerEndpoint,
        username: &str,
        password: &Password,
    ) -> Result<UserToken, Error> {
        let found = self.users.iter().find(|u| u.name == username);
        match found {
            Some(u) if same(u.password.as_bytes(), password.get().as_bytes()) => Ok(UserToken(u.name.clone())),
            Some(_) => {
                tracing::warn!(user = username, "OPC UA: wrong password; session refused");
                Err(Error::new(StatusCode::BadUserAccessDenied, format!("wrong password for {username:?}")))
            }
            None => {
                tracing::warn!(user = username, "OPC UA: unknown user; session refused");
                Err(Error::new(StatusCode::BadUserAccessDenied, format!("no user {username:?}")))
            }
        }
    }

    /// Every method of the model changes something: never for an anonymous session.
    /// (Also asked when a client reads a method's UserExecutable attribute: what it says is
    /// what a call gets.)
    fn is_user_executable(&self, token: &UserToken, _method_id: &NodeId) -> bool {
        !token.is_anonymous() && token.0 != ANONYMOUS_USER_TOKEN_ID
    }

    fn user_token_policies(&self, endpoint: &ServerEndpoint) -> Vec<UserTokenPolicy> {
        let mut out = Vec::new();
        if self.anonymous {
            out.push(UserTokenPolicy {
                policy_id: UAString::from(ANONYMOUS_POLICY),
                token_type: UserTokenType::Anonymous,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: UAString::null(),
            });
        }
        if !self.users.is_empty() {
            // The password travels encrypted with the server's certificate even on the None
            // endpoint (the endpoint's password policy is Basic256Sha256): the token policy
            // says so, and clients (asyncua, UaExpert) encrypt as it asks.
            out.push(UserTokenPolicy {
                policy_id: user_pass_security_policy_id(endpoint),
                token_type: UserTokenType::UserName,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: UAString::from(endpoint.password_security_policy().to_uri()),
            });
        }
        out
    }
}

/// The password policy of every endpoint: the None endpoint's passwords are encrypted as the
/// secure endpoints' are.
pub fn password_policy() -> String {
    SecurityPolicy::Basic256Sha256.to_uri().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passwords_are_compared_whole() {
        assert!(same(b"secret-1", b"secret-1"));
        assert!(!same(b"secret-1", b"secret-2"));
        assert!(!same(b"secret", b"secret-1"));
    }
}
