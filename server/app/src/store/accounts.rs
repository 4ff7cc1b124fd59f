//! Accounts: added, found by their token's hash or id, listed, and an account's sessions.

use super::Store;
use super::records::{
    SELECT_ACCOUNT, SELECT_SESSION, StoreError, StoredAccount, StoredSession, row_to_account,
    row_to_session,
};

impl Store {
    /// Adds an account.
    pub fn insert_account(&self, a: &StoredAccount) -> Result<(), StoreError> {
        self.write(vec![(
            "INSERT INTO accounts (id, name, role, token_hash, created_unix_s)
             VALUES (?1, ?2, ?3, ?4, ?5)"
                .into(),
            vec![
                (&a.id).into(),
                (&a.name).into(),
                (&a.role).into(),
                (&a.token_hash).into(),
                a.created_unix_s.into(),
            ],
        )])
    }

    /// The account whose token hashes to `token_hash`.
    pub fn account_by_token_hash(
        &self,
        token_hash: &str,
    ) -> Result<Option<StoredAccount>, StoreError> {
        Ok(self
            .rows(
                format!("{SELECT_ACCOUNT} WHERE token_hash = ?1"),
                vec![token_hash.into()],
                "account",
                row_to_account,
            )?
            .pop())
    }

    /// One account.
    pub fn account(&self, id: &str) -> Result<Option<StoredAccount>, StoreError> {
        Ok(self
            .rows(
                format!("{SELECT_ACCOUNT} WHERE id = ?1"),
                vec![id.into()],
                &format!("account {id}"),
                row_to_account,
            )?
            .pop())
    }

    /// Every account, oldest first.
    pub fn accounts(&self) -> Result<Vec<StoredAccount>, StoreError> {
        self.rows(
            format!("{SELECT_ACCOUNT} ORDER BY created_unix_s"),
            vec![],
            "account",
            row_to_account,
        )
    }

    /// An account's sessions, oldest first.
    pub fn sessions_of(&self, account_id: &str) -> Result<Vec<StoredSession>, StoreError> {
        self.rows(
            format!("{SELECT_SESSION} WHERE account_id = ?1 ORDER BY created_unix_s"),
            vec![account_id.into()],
            &format!("session of account {account_id}"),
            row_to_session,
        )
    }
}
