//! Robot identities.

use std::fmt;
use std::sync::Arc;

use crate::error::{Problem, ValidationError};

/// A robot's identity: 1 to [`RobotId::MAX_LEN`] characters from
/// `[A-Za-z0-9_.-]`, so that it is safe in file names, logs and metrics.
///
/// The text is shared: a clone (every estimate names its robots) costs a
/// reference count, not an allocation.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct RobotId(Arc<str>);

impl RobotId {
    /// Longest accepted id, in characters.
    pub const MAX_LEN: usize = 64;

    /// Validates `s`; errors name `field`.
    pub fn parse(s: &str, field: &str) -> Result<Self, ValidationError> {
        let err = |p| ValidationError::new(field, p);
        if s.is_empty() {
            return Err(err(Problem::Empty));
        }
        let len = s.chars().count();
        if len > Self::MAX_LEN {
            return Err(err(Problem::TooLong { len, max: Self::MAX_LEN }));
        }
        if let Some(c) = s.chars().find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '-'))) {
            return Err(err(Problem::InvalidCharacter(c)));
        }
        Ok(RobotId(Arc::from(s)))
    }

    /// The id as text.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl fmt::Display for RobotId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::str::FromStr for RobotId {
    type Err = ValidationError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        RobotId::parse(s, "robot_id")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accepts_and_rejects() {
        assert!(RobotId::parse("pioneer-1.left_arm", "id").is_ok());
        assert_eq!(RobotId::parse("", "id").unwrap_err().problem, Problem::Empty);
        let long = "a".repeat(65);
        assert!(matches!(
            RobotId::parse(&long, "id").unwrap_err().problem,
            Problem::TooLong { len: 65, max: 64 }
        ));
        let e = RobotId::parse("robot 1", "hello.robot_id").unwrap_err();
        assert_eq!(e.problem, Problem::InvalidCharacter(' '));
        assert!(e.to_string().starts_with("hello.robot_id: "));
    }
}
