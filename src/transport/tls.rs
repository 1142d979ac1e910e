//! Modbus/TCP Security: TLS over a TCP socket, with rustls.
//!
//! - **Crypto provider: ring.** It builds from a clean clone with nothing but the C
//!   compiler the library already needs (aws-lc-rs, rustls' default, also needs cmake
//!   and takes minutes to build), and it covers every suite offered here.
//! - **Versions**: TLS 1.2 and 1.3, never lower (the specification's );
//!   1.3 only on request (`modbus_set_tls_min_version`).
//! - **Cipher suites** (ring's, all of them): TLS 1.3 `TLS13_AES_128_GCM_SHA256`,
//!   `TLS13_AES_256_GCM_SHA384`, `TLS13_CHACHA20_POLY1305_SHA256`; TLS 1.2
//!   `TLS_ECDHE_ECDSA_WITH_AES_128_GCM_SHA256`, `..._AES_256_GCM_SHA384`,
//!   `..._CHACHA20_POLY1305_SHA256` and the same three with `ECDHE_RSA`.
//!   AES-128-GCM first (rustls puts AES-256 first): the specification recommends its
//!   AES-128-GCM suites, TLS 1.3 makes `TLS13_AES_128_GCM_SHA256` mandatory,
//!   and it is the cheaper one: a resumed handshake takes 6% fewer instructions (its
//!   key schedule is SHA-256's), a transaction 4% fewer. A server follows the
//!   client's order (rustls' default), so a peer that asks for AES-256 first gets it.
//!   The specification's mandatory `TLS_RSA_WITH_AES_128_CBC_SHA256` and
//!   `TLS_RSA_WITH_NULL_SHA256` are not offered: RSA key exchange has no forward
//!   secrecy, CBC with MAC-then-encrypt invites padding oracles, and NULL encrypts
//!   nothing; rustls implements none of them.
//! - **Mutual authentication**: a server always requires a client certificate that
//!   chains to its CA; a client always verifies the server's chain and its name or
//!   address (a client without a certificate of its own can connect, and the server
//!   refuses it: the refusal is the server's to make).
//! - **Session resumption**: a context keeps its configurations, and with them
//!   rustls' session caches (client: in memory; server: stateful, plus tickets).
//!
//! A [`Session`] is one connection: rustls' state, the plaintext received and not
//! yet taken, and the peer's role. The driver reads and writes through it.

use std::collections::HashMap;
use std::ffi::{CStr, CString};
use std::io;
use std::ops::Range;
use std::sync::Arc;
use std::time::Duration;

use rustls::client::{ClientConnectionData, UnbufferedClientConnection};
use rustls::kernel::KernelConnection;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer, ServerName};
use rustls::server::{ServerConnectionData, UnbufferedServerConnection, WebPkiClientVerifier};
use rustls::unbuffered::{ConnectionState, EncodeError, UnbufferedStatus};
use rustls::{
    AlertDescription, CertificateError, ClientConfig, ConnectionTrafficSecrets, PeerIncompatible, RootCertStore,
    ServerConfig, SupportedProtocolVersion,
};

use super::record::{self, MAX_FRAGMENT};
use super::room;
use super::{Ready, now, to_timespec, wait_or_wake};
use crate::error::{
    EMBTLS, EMBTLSCACERT, EMBTLSCONFIG, EMBTLSEXPIRED, EMBTLSNAME, EMBTLSNOCERT, EMBTLSPASSWORD, EMBTLSUNKNOWNCA,
    EMBTLSVERSION, Error, Result, errno,
};
use crate::proto::security;
pub use crate::proto::security::RecordCut;
use crate::proto::session::Timeout;

/// `MODBUS_TLS_1_2`, `MODBUS_TLS_1_3`: the protocol versions, as on the wire.
pub const TLS_1_2: u16 = 0x0303;
pub const TLS_1_3: u16 = 0x0304;

/// ring's suites, AES-128-GCM first in each version (the module's notes say why).
fn provider() -> Arc<rustls::crypto::CryptoProvider> {
    use rustls::crypto::ring::cipher_suite::*;
    let cipher_suites = vec![
        TLS13_AES_128_GCM_SHA256,
        TLS13_AES_256_GCM_SHA384,
        TLS13_CHACHA20_POLY1305_SHA256,
        TLS_ECDHE_ECDSA_WITH_AES_128_GCM_SHA256,
        TLS_ECDHE_ECDSA_WITH_AES_256_GCM_SHA384,
        TLS_ECDHE_ECDSA_WITH_CHACHA20_POLY1305_SHA256,
        TLS_ECDHE_RSA_WITH_AES_128_GCM_SHA256,
        TLS_ECDHE_RSA_WITH_AES_256_GCM_SHA384,
        TLS_ECDHE_RSA_WITH_CHACHA20_POLY1305_SHA256,
    ];
    Arc::new(rustls::crypto::CryptoProvider { cipher_suites, ..rustls::crypto::ring::default_provider() })
}

/// The errno a rustls failure is reported with.
pub fn error_of(e: &rustls::Error) -> Error {
    use rustls::Error as E;
    Error(match e {
        E::NoCertificatesPresented | E::AlertReceived(AlertDescription::CertificateRequired) => EMBTLSNOCERT,
        E::InvalidCertificate(
            CertificateError::Expired
            | CertificateError::ExpiredContext { .. }
            | CertificateError::NotValidYet
            | CertificateError::NotValidYetContext { .. },
        )
        | E::AlertReceived(AlertDescription::CertificateExpired) => EMBTLSEXPIRED,
        E::InvalidCertificate(CertificateError::NotValidForName | CertificateError::NotValidForNameContext { .. }) => {
            EMBTLSNAME
        }
        // webpki's reason has no variant of rustls' own; its name is its text.
        E::InvalidCertificate(CertificateError::Other(other)) if other.to_string() == "CaUsedAsEndEntity" => {
            EMBTLSCACERT
        }
        E::InvalidCertificate(CertificateError::UnknownIssuer | CertificateError::BadSignature)
        | E::AlertReceived(AlertDescription::UnknownCA | AlertDescription::BadCertificate) => EMBTLSUNKNOWNCA,
        E::AlertReceived(AlertDescription::ProtocolVersion)
        | E::PeerIncompatible(
            PeerIncompatible::Tls12NotOffered
            | PeerIncompatible::Tls12NotOfferedOrEnabled
            | PeerIncompatible::SupportedVersionsExtensionRequired
            | PeerIncompatible::ServerDoesNotSupportTls12Or13
            | PeerIncompatible::ServerTlsVersionIsDisabledByOurConfig
            // A ClientHello without signature algorithms is from before TLS 1.2.
            | PeerIncompatible::SignatureAlgorithmsExtensionRequired,
        ) => EMBTLSVERSION,
        _ => EMBTLS,
    })
}

fn io_error(e: io::Error) -> Error {
    Error(e.raw_os_error().unwrap_or(errno::ECONNRESET))
}

/// The TLS settings of a context (`modbus_set_tls_*`) and the configurations made
/// from them (kept, with their session caches, until a setting changes).
pub struct TlsSettings {
    chain: Vec<CertificateDer<'static>>,
    key: Option<PrivateKeyDer<'static>>,
    roots: Vec<CertificateDer<'static>>,
    min_version: u16,
    server_name: Option<String>,
    client: Option<Arc<ClientConfig>>,
    server: Option<Arc<ServerConfig>>,
}

impl Default for TlsSettings {
    fn default() -> Self {
        TlsSettings {
            chain: Vec::new(),
            key: None,
            roots: Vec::new(),
            min_version: TLS_1_2,
            server_name: None,
            client: None,
            server: None,
        }
    }
}

/// The private key of a PEM text: PKCS#8, PKCS#1 (RSA) or SEC1 (EC), or an encrypted
/// PKCS#8 key ("ENCRYPTED PRIVATE KEY": PBES2 with PBKDF2 or scrypt and AES-CBC, what
/// `openssl genpkey -aes256` and `openssl pkcs8 -topk8` write), decrypted with
/// `password`. EMBTLSPASSWORD: an encrypted key and no password, or a password that
/// does not decrypt it. EINVAL: no key, or an encryption not supported (PBES1, or
/// OpenSSL's older "Proc-Type: 4,ENCRYPTED" PEM headers). A password given for a
/// key that is not encrypted is not used.
fn private_key(pem: &[u8], password: Option<&[u8]>) -> Result<PrivateKeyDer<'static>> {
    use pkcs8::der::Decode;
    const BEGIN: &[u8] = b"-----BEGIN ENCRYPTED PRIVATE KEY-----";
    const END: &[u8] = b"-----END ENCRYPTED PRIVATE KEY-----";
    let find = |hay: &[u8], needle: &[u8]| hay.windows(needle.len()).position(|w| w == needle);
    let Some(begin) = find(pem, BEGIN) else {
        if find(pem, b"Proc-Type: 4,ENCRYPTED").is_some() {
            return Err(Error::INVALID);
        }
        return PrivateKeyDer::from_pem_slice(pem).map_err(|_| Error::INVALID);
    };
    let Some(password) = password else { return Err(Error(EMBTLSPASSWORD)) };
    let end = find(&pem[begin..], END).ok_or(Error::INVALID)? + begin + END.len();
    let (_, der) = pkcs8::der::pem::decode_vec(&pem[begin..end]).map_err(|_| Error::INVALID)?;
    let info = pkcs8::EncryptedPrivateKeyInfo::from_der(&der).map_err(|_| Error::INVALID)?;
    if !affordable(&info.encryption_algorithm) {
        return Err(Error::INVALID);
    }
    let plain = info.decrypt(password).map_err(|e| match e {
        // pkcs5 0.7 reports a bad padding (a wrong password) as EncryptFailed.
        pkcs8::Error::EncryptedPrivateKey(pkcs8::pkcs5::Error::DecryptFailed | pkcs8::pkcs5::Error::EncryptFailed) => {
            Error(EMBTLSPASSWORD)
        }
        // A wrong password that happens to leave valid padding decrypts to garbage.
        pkcs8::Error::Asn1(_) | pkcs8::Error::KeyMalformed => Error(EMBTLSPASSWORD),
        _ => Error::INVALID,
    })?;
    pkcs8::PrivateKeyInfo::from_der(plain.as_bytes()).map_err(|_| Error(EMBTLSPASSWORD))?;
    Ok(PrivateKeyDer::Pkcs8(plain.as_bytes().to_vec().into()))
}

/// The most PBKDF2 iterations a key may ask for (openssl writes 2,048; current advice
/// is some 600,000 with SHA-256; 10 million take seconds).
const MAX_PBKDF2_ITERATIONS: u32 = 10_000_000;
/// The most memory scrypt may need to decrypt a key (128 N r bytes; openssl's
/// default N = 16384, r = 8 needs 16 MiB), and the most parallel passes.
const MAX_SCRYPT_MEMORY: u64 = 256 << 20;
const MAX_SCRYPT_PARALLELIZATION: u16 = 16;

/// Whether decrypting a key with these parameters takes reasonable time and memory
/// (a key file's parameters could otherwise ask for hours, or more memory than
/// there is: an allocation failure aborts the process) and the parameters are
/// valid (scrypt's N a power of two above 1, r and p above 0).
fn affordable(scheme: &pkcs8::pkcs5::EncryptionScheme<'_>) -> bool {
    use pkcs8::pkcs5::EncryptionScheme;
    use pkcs8::pkcs5::pbes2::Kdf;
    match scheme {
        EncryptionScheme::Pbes2(params) => match &params.kdf {
            Kdf::Pbkdf2(k) => (1..=MAX_PBKDF2_ITERATIONS).contains(&k.iteration_count),
            Kdf::Scrypt(k) => {
                let (n, r, p) = (k.cost_parameter, u64::from(k.block_size), k.parallelization);
                n >= 2
                    && n.is_power_of_two()
                    && r > 0
                    && (1..=MAX_SCRYPT_PARALLELIZATION).contains(&p)
                    && n.checked_mul(r).and_then(|x| x.checked_mul(128)).is_some_and(|m| m <= MAX_SCRYPT_MEMORY)
            }
            _ => false,
        },
        // PBES1: decrypt refuses it (EINVAL).
        _ => true,
    }
}

/// Reads a PEM file; an unreadable file gives the errno of the failure.
pub fn read_file(path: &std::path::Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(io_error)
}

impl TlsSettings {
    /// The settings of one client's line of a server runner: the listening
    /// context's server configuration, made already.
    pub fn serving(server: Arc<ServerConfig>) -> Self {
        TlsSettings { server: Some(server), ..TlsSettings::default() }
    }

    fn changed(&mut self) {
        self.client = None;
        self.server = None;
    }

    /// The certificate chain (leaf first) and private key, PEM; the key decrypted
    /// with `password` when it is encrypted (see [`private_key`]). EINVAL when either
    /// holds nothing usable or the key does not belong to the certificate.
    pub fn set_certificate_pem(&mut self, chain_pem: &[u8], key_pem: &[u8], password: Option<&[u8]>) -> Result<()> {
        let chain: Vec<_> = CertificateDer::pem_slice_iter(chain_pem)
            .collect::<core::result::Result<_, _>>()
            .map_err(|_| Error::INVALID)?;
        let key = private_key(key_pem, password)?;
        if chain.is_empty() {
            return Err(Error::INVALID);
        }
        // The key must load and match the certificate: a server configuration
        // checks both.
        ServerConfig::builder_with_provider(provider())
            .with_safe_default_protocol_versions()
            .map_err(|_| Error::INVALID)?
            .with_no_client_auth()
            .with_single_cert(chain.clone(), key.clone_key())
            .map_err(|_| Error::INVALID)?;
        self.chain = chain;
        self.key = Some(key);
        self.changed();
        Ok(())
    }

    /// The CA certificates (PEM, one or more) that peers' chains must lead to.
    pub fn set_ca_pem(&mut self, pem: &[u8]) -> Result<()> {
        let certs: Vec<_> =
            CertificateDer::pem_slice_iter(pem).collect::<core::result::Result<_, _>>().map_err(|_| Error::INVALID)?;
        let mut store = RootCertStore::empty();
        for cert in &certs {
            store.add(cert.clone()).map_err(|_| Error::INVALID)?;
        }
        if certs.is_empty() {
            return Err(Error::INVALID);
        }
        self.roots = certs;
        self.changed();
        Ok(())
    }

    pub fn set_min_version(&mut self, version: u16) -> Result<()> {
        if version != TLS_1_2 && version != TLS_1_3 {
            return Err(Error::INVALID);
        }
        self.min_version = version;
        self.changed();
        Ok(())
    }

    /// The name (or address) a client checks the server's certificate against,
    /// instead of the address it connects to; `None`: that address.
    pub fn set_server_name(&mut self, name: Option<String>) -> Result<()> {
        if let Some(n) = &name {
            ServerName::try_from(n.as_str()).map_err(|_| Error::INVALID)?;
        }
        self.server_name = name;
        Ok(())
    }

    fn versions(&self) -> &'static [&'static SupportedProtocolVersion] {
        static TLS13_ONLY: [&SupportedProtocolVersion; 1] = [&rustls::version::TLS13];
        if self.min_version == TLS_1_3 { &TLS13_ONLY } else { rustls::ALL_VERSIONS }
    }

    fn root_store(&self) -> Result<Arc<RootCertStore>> {
        if self.roots.is_empty() {
            return Err(Error(EMBTLSCONFIG));
        }
        let mut store = RootCertStore::empty();
        for cert in &self.roots {
            store.add(cert.clone()).map_err(|_| Error(EMBTLSCONFIG))?;
        }
        Ok(Arc::new(store))
    }

    /// The client's configuration: the CA to verify the server with (required), and
    /// the client's own certificate when set.
    pub fn client_config(&mut self) -> Result<Arc<ClientConfig>> {
        if let Some(c) = &self.client {
            return Ok(Arc::clone(c));
        }
        let builder = ClientConfig::builder_with_provider(provider())
            .with_protocol_versions(self.versions())
            .map_err(|_| Error(EMBTLSCONFIG))?
            .with_root_certificates(self.root_store()?);
        let config = match &self.key {
            Some(key) => {
                builder.with_client_auth_cert(self.chain.clone(), key.clone_key()).map_err(|_| Error(EMBTLSCONFIG))?
            }
            None => builder.with_no_client_auth(),
        };
        // The records are protected by `record` once the handshake is done.
        let mut config = config;
        config.enable_secret_extraction = true;
        let config = Arc::new(config);
        self.client = Some(Arc::clone(&config));
        Ok(config)
    }

    /// The server's configuration: its certificate and key, and the CA every client
    /// certificate must chain to (all required).
    pub fn server_config(&mut self) -> Result<Arc<ServerConfig>> {
        if let Some(c) = &self.server {
            return Ok(Arc::clone(c));
        }
        let Some(key) = &self.key else { return Err(Error(EMBTLSCONFIG)) };
        let verifier = WebPkiClientVerifier::builder_with_provider(self.root_store()?, provider())
            .build()
            .map_err(|_| Error(EMBTLSCONFIG))?;
        let mut config = ServerConfig::builder_with_provider(provider())
            .with_protocol_versions(self.versions())
            .map_err(|_| Error(EMBTLSCONFIG))?
            .with_client_cert_verifier(verifier)
            .with_single_cert(self.chain.clone(), key.clone_key())
            .map_err(|_| Error(EMBTLSCONFIG))?;
        config.ticketer = rustls::crypto::ring::Ticketer::new().map_err(|_| Error(EMBTLSCONFIG))?;
        // One TLS 1.3 ticket per connection (rustls sends 2): a context has one
        // connection at a time, and each resumption takes one ticket and brings a new
        // one; the second cost both sides a key derivation and a record each handshake.
        config.send_tls13_tickets = 1;
        // The records are protected by `record` once the handshake is done.
        config.enable_secret_extraction = true;
        let config = Arc::new(config);
        self.server = Some(Arc::clone(&config));
        Ok(config)
    }

    /// A client connection to `host` (the address or node connected to, unless a
    /// server name was set).
    pub fn connect(&mut self, host: &str) -> Result<Conn> {
        let config = self.client_config()?;
        let name = self.server_name.as_deref().unwrap_or(host);
        let name = ServerName::try_from(name.to_owned()).map_err(|_| Error(EMBTLSNAME))?;
        let conn = UnbufferedClientConnection::new(config, name).map_err(|e| error_of(&e))?;
        Ok(Conn::new(Peer::Client(Box::new(conn))))
    }

    /// A server connection.
    pub fn accept(&mut self) -> Result<Conn> {
        let config = self.server_config()?;
        let conn = UnbufferedServerConnection::new(config).map_err(|e| error_of(&e))?;
        Ok(Conn::new(Peer::Server(Box::new(conn))))
    }
}

/// The room a connection starts with for the records it receives; it grows to the
/// largest record that arrives (a handshake's certificates), up to a record's most.
const INITIAL_INPUT: usize = 2048;
const MAX_RECORD: usize = 5 + 0xFFFF;
/// The room for records to send a session keeps after its handshake (whose flight of
/// certificates is larger): a Modbus ADU's record (260 bytes and a record's 29 at
/// most) and a key update's; it grows again for more, once.
const OUTPUT_KEPT: usize = 512;

/// rustls' unbuffered connection of either side (the two have no common type).
enum Peer {
    Client(Box<UnbufferedClientConnection>),
    Server(Box<UnbufferedServerConnection>),
}

/// What [`Conn::advance`] stopped at.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Stop {
    /// The handshake is done: application data may be sent.
    Traffic,
    /// The handshake needs more records from the peer.
    Blocked,
    /// Both ends sent close_notify.
    Closed,
    /// Application data was read, and no other record is held (whatever rustls has
    /// to say still, a key update's answer, goes out before the next record sent).
    Read,
}

/// The buffers of a connection: records received and not processed yet
/// (`input[..have]`, decrypted in place there by rustls), records to send
/// (`output[sent..end]`, encrypted in place there), and plaintext received and not
/// taken yet (`plain[start..]`). They grow to what the connection needs and are then
/// reused: a transaction allocates nothing of ours.
struct Buffers {
    input: Vec<u8>,
    have: usize,
    output: Out,
    plain: Vec<u8>,
    start: usize,
    /// The peer sent close_notify.
    peer_closed: bool,
}

impl Buffers {
    /// Drops the first `n` bytes of input (records rustls processed).
    fn consume(&mut self, n: usize) {
        if n > 0 {
            self.input.copy_within(n..self.have, 0);
            self.have -= n;
        }
    }

    /// The room a read of records may fill: after what is held, growing when a
    /// record held in part does not fit.
    fn input_room(&mut self) -> &mut [u8] {
        if self.have == self.input.len() {
            let need = if self.have >= 5 {
                5 + u16::from_be_bytes([self.input[3], self.input[4]]) as usize
            } else {
                INITIAL_INPUT
            };
            let size = need.max(self.have + 1).clamp(INITIAL_INPUT, MAX_RECORD);
            self.input.resize(size, 0);
        }
        &mut self.input[self.have..]
    }
}

/// Records to send: `buf[sent..end]`.
#[derive(Default)]
struct Out {
    buf: Vec<u8>,
    sent: usize,
    end: usize,
}

impl Out {
    /// Room for `at_least` more bytes after `end`.
    fn room(&mut self, at_least: usize) -> &mut [u8] {
        if self.buf.len() < self.end + at_least {
            self.buf.resize(self.end + at_least, 0);
        }
        &mut self.buf[self.end..]
    }

    /// Records wait to go out.
    fn waiting(&self) -> bool {
        self.sent < self.end
    }

    /// Gives back the room beyond `keep` bytes when nothing waits to go out.
    fn trim(&mut self, keep: usize) {
        if !self.waiting() && self.buf.capacity() > keep {
            (self.sent, self.end) = (0, 0);
            self.buf.truncate(keep);
            self.buf.shrink_to_fit();
        }
    }

    /// Sends the records as far as the socket takes them without waiting: true when
    /// all are out.
    fn flush(&mut self, fd: i32) -> Result<bool> {
        while self.sent < self.end {
            match super::send(fd, &self.buf[self.sent..self.end], libc::MSG_DONTWAIT) {
                Ok(n) => self.sent += n,
                Err(e) if e.0 == libc::EAGAIN => return Ok(false),
                Err(e) if e.0 == libc::EINTR => {}
                Err(e) => return Err(e),
            }
        }
        self.sent = 0;
        self.end = 0;
        Ok(true)
    }

    /// Sends the records, waiting for room until `deadline`, which the first wait sets
    /// to `timeout` from then if it is not set (a send that does not wait reads no
    /// clock).
    fn flush_within(
        &mut self,
        fd: i32,
        timeout: Timeout,
        deadline: &mut Option<Duration>,
        stopping: &dyn Fn() -> bool,
    ) -> Result<()> {
        while !self.flush(fd)? {
            let until = *deadline.get_or_insert_with(|| now() + timeout.duration());
            wait_until(fd, libc::POLLOUT, Some(until), stopping)?;
        }
        Ok(())
    }
}

/// The part of rustls' unbuffered API [`Conn`] drives, on either side.
trait Unbuffered {
    type Data;
    fn process<'c, 'i>(&'c mut self, input: &'i mut [u8]) -> UnbufferedStatus<'c, 'i, Self::Data>;
}

impl Unbuffered for UnbufferedClientConnection {
    type Data = ClientConnectionData;
    fn process<'c, 'i>(&'c mut self, input: &'i mut [u8]) -> UnbufferedStatus<'c, 'i, Self::Data> {
        self.process_tls_records(input)
    }
}

impl Unbuffered for UnbufferedServerConnection {
    type Data = ServerConnectionData;
    fn process<'c, 'i>(&'c mut self, input: &'i mut [u8]) -> UnbufferedStatus<'c, 'i, Self::Data> {
        self.process_tls_records(input)
    }
}

/// Processes the records `b` holds until rustls needs more of them or the handshake
/// is done: application data goes to the plaintext, what rustls has to send to the
/// output.
fn advance<C: Unbuffered>(conn: &mut C, b: &mut Buffers) -> core::result::Result<Stop, rustls::Error> {
    loop {
        let status = conn.process(&mut b.input[..b.have]);
        let discard = status.discard;
        let step = match status.state {
            Err(e) => Err(e),
            Ok(ConnectionState::ReadTraffic(mut traffic)) => {
                let mut got = Ok(None);
                while let Some(record) = traffic.next_record() {
                    match record {
                        Ok(record) => {
                            if b.start == b.plain.len() {
                                b.plain.clear();
                                b.start = 0;
                            }
                            b.plain.extend_from_slice(record.payload);
                        }
                        Err(e) => {
                            got = Err(e);
                            break;
                        }
                    }
                }
                match got {
                    // The last record held: no need to ask rustls again.
                    Ok(None) if b.have == discard => Ok(Some(Stop::Read)),
                    got => got,
                }
            }
            Ok(ConnectionState::EncodeTlsData(mut data)) => {
                let mut room = 0;
                loop {
                    match data.encode(b.output.room(room)) {
                        Ok(n) => {
                            b.output.end += n;
                            break;
                        }
                        Err(EncodeError::InsufficientSize(s)) => room = s.required_size,
                        Err(EncodeError::AlreadyEncoded) => break,
                    }
                }
                Ok(None)
            }
            // The output is sent by the caller before it reads again.
            Ok(ConnectionState::TransmitTlsData(data)) => {
                data.done();
                Ok(None)
            }
            Ok(ConnectionState::PeerClosed) => {
                b.peer_closed = true;
                Ok(None)
            }
            Ok(ConnectionState::Closed) => {
                b.peer_closed = true;
                Ok(Some(Stop::Closed))
            }
            Ok(ConnectionState::WriteTraffic(_)) => Ok(Some(Stop::Traffic)),
            Ok(_) => Ok(Some(Stop::Blocked)),
        };
        b.consume(discard);
        match step {
            Ok(None) => {}
            Ok(Some(stop)) => return Ok(stop),
            Err(e) => return Err(e),
        }
    }
}

/// One TLS connection's state and buffers, on rustls' unbuffered API: records are
/// decrypted in place in the input buffer one `recv` filled, and encrypted into the
/// output buffer one `send` empties.
pub struct Conn {
    peer: Peer,
    b: Buffers,
}

impl Conn {
    fn new(peer: Peer) -> Self {
        let b = Buffers {
            input: Vec::new(),
            have: 0,
            output: Out::default(),
            plain: Vec::new(),
            start: 0,
            peer_closed: false,
        };
        Conn { peer, b }
    }

    /// rustls' state common to both sides (certificates, version, suite).
    fn common(&self) -> &rustls::CommonState {
        match &self.peer {
            Peer::Client(c) => c,
            Peer::Server(s) => s,
        }
    }

    fn advance(&mut self) -> core::result::Result<Stop, rustls::Error> {
        match &mut self.peer {
            Peer::Client(c) => advance(&mut **c, &mut self.b),
            Peer::Server(s) => advance(&mut **s, &mut self.b),
        }
    }

    /// Output waits to go out.
    fn wants_write(&self) -> bool {
        self.b.output.waiting()
    }

    /// Sends the output as far as the socket takes it without waiting: true when all
    /// is out.
    fn flush(&mut self, fd: i32) -> Result<bool> {
        self.b.output.flush(fd)
    }

    /// One `recv` of records (with `flags`; a server's handshake stops at the end of
    /// the record with `cut`): the bytes read, 0 at the end of the stream.
    fn read(&mut self, fd: i32, flags: i32, cut: Option<&mut RecordCut>) -> Result<usize> {
        let room = self.b.input_room();
        let room = match &cut {
            Some(cut) => {
                let limit = cut.limit().min(room.len());
                &mut room[..limit]
            }
            None => room,
        };
        let n = super::recv(fd, room, flags)?;
        if let Some(cut) = cut {
            cut.advance(&room[..n]);
        }
        self.b.have += n;
        Ok(n)
    }

    /// After a failure: the alert rustls queued goes out if it can without waiting.
    fn send_alert(&mut self, fd: i32) {
        let _ = self.advance();
        let _ = self.flush(fd);
    }
}

/// Waits for `events` on `fd` until `deadline` on the monotonic clock (`None`:
/// forever), resuming after signals; `stopping` ends it (the closer shuts the
/// socket down, which wakes the wait).
fn wait_until(fd: i32, events: libc::c_short, deadline: Option<Duration>, stopping: &dyn Fn() -> bool) -> Result<()> {
    loop {
        if stopping() {
            return Err(Error::STOPPED);
        }
        let mut left = deadline.map(|d| to_timespec(d.saturating_sub(now())));
        match wait_or_wake(fd, events, -1, left.as_mut()) {
            Ok(Ready::TimedOut) => return Err(Error::TIMED_OUT),
            Ok(_) => return Ok(()),
            Err(e) if e.0 == libc::EINTR => {}
            Err(e) => return Err(e),
        }
    }
}

/// The handshake of `conn` on `fd`, until `deadline`. A refusal sends its alert
/// before it is reported.
pub fn handshake(
    fd: i32,
    conn: &mut Conn,
    cut: Option<&mut RecordCut>,
    deadline: Option<Duration>,
    stopping: &dyn Fn() -> bool,
) -> Result<()> {
    // A close from another thread or a signal handler shuts the socket down to wake
    // the wait: what the socket then says (end of stream, reset) is the stop's doing.
    handshake_steps(fd, conn, cut, deadline, stopping).map_err(|e| if stopping() { Error::STOPPED } else { e })
}

fn handshake_steps(
    fd: i32,
    conn: &mut Conn,
    cut: Option<&mut RecordCut>,
    deadline: Option<Duration>,
    stopping: &dyn Fn() -> bool,
) -> Result<()> {
    let mut cut = cut;
    loop {
        match handshake_step(fd, conn, cut.as_deref_mut())? {
            Progress::Done => return Ok(()),
            Progress::Wants(events) => wait_until(fd, events, deadline, stopping)?,
        }
    }
}

/// Where a handshake stands after [`handshake_step`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress {
    Done,
    /// It goes on once the socket is ready for these poll(2) events.
    Wants(libc::c_short),
}

/// The handshake of `conn` on `fd` as far as it goes without waiting: what it has
/// to send is sent, what has arrived is read. A refusal sends its alert before it is
/// reported. The blocking handshake ([`handshake`]) waits between these steps; the
/// event-driven client returns to the application's loop.
pub fn handshake_step(fd: i32, conn: &mut Conn, cut: Option<&mut RecordCut>) -> Result<Progress> {
    let mut cut = cut;
    loop {
        match conn.flush(fd) {
            Ok(true) => {}
            Ok(false) => return Ok(Progress::Wants(libc::POLLOUT)),
            Err(e) => return Err(refusal_after_failed_write(fd, conn, cut.as_deref_mut(), e)),
        }
        match conn.advance() {
            Ok(Stop::Traffic) if !conn.wants_write() => return Ok(Progress::Done),
            Ok(Stop::Traffic | Stop::Read) => {}
            Ok(Stop::Closed) => return Err(Error::CONN_RESET),
            Ok(Stop::Blocked) if conn.wants_write() => {}
            Ok(Stop::Blocked) => match conn.read(fd, libc::MSG_DONTWAIT, cut.as_deref_mut()) {
                Ok(0) => return Err(Error::CONN_RESET),
                Ok(_) => {}
                Err(e) if e.0 == libc::EAGAIN => return Ok(Progress::Wants(libc::POLLIN)),
                Err(e) if e.0 == libc::EINTR => {}
                Err(e) => return Err(e),
            },
            Err(e) => {
                conn.send_alert(fd);
                return Err(error_of(&e));
            }
        }
    }
}

/// Records a failed handshake write leaves unread, at most (an alert is one record;
/// what the peer sent before it, a flight of a few).
const MAX_RECORDS_AFTER_FAILED_WRITE: usize = 16;

/// The error of a handshake whose write failed with `failed` (EPIPE, ECONNRESET): a
/// peer that refuses us (our certificate, say) sends its alert and closes, and when
/// our writes are still going out, the close resets the connection and the next
/// write fails before we have read the alert, which waits in the socket's receive
/// queue. What the peer sent is read without waiting (a bounded number of reads)
/// and given to rustls: an alert among it is the error (EMBTLSUNKNOWNCA for a
/// refused certificate); without one, `failed`.
fn refusal_after_failed_write(fd: i32, conn: &mut Conn, cut: Option<&mut RecordCut>, failed: Error) -> Error {
    let mut cut = cut;
    // What was to go out will not.
    conn.b.output = Out::default();
    for _ in 0..MAX_RECORDS_AFTER_FAILED_WRITE {
        match conn.read(fd, libc::MSG_DONTWAIT, cut.as_deref_mut()) {
            Ok(0) => break,
            Ok(_) => {}
            Err(e) if e.0 == libc::EINTR => continue,
            Err(_) => break,
        }
        match conn.advance() {
            Err(e @ rustls::Error::AlertReceived(_)) => return error_of(&e),
            Err(_) => break,
            Ok(_) => {}
        }
    }
    failed
}

/// What a handshake agreed on, for the debug trace.
pub fn describe_session(conn: &Conn) -> String {
    let conn = conn.common();
    let version = conn.protocol_version().map_or_else(|| "?".to_owned(), |v| format!("{v:?}"));
    let suite = conn.negotiated_cipher_suite().map_or_else(|| "?".to_owned(), |s| format!("{:?}", s.suite()));
    let resumed = matches!(conn.handshake_kind(), Some(rustls::HandshakeKind::Resumed));
    format!("{version}, {suite}{}", if resumed { ", resumed" } else { "" })
}

/// rustls' connection once the handshake is done, as far as it still has a part:
/// TLS 1.3 key updates, and a server's session tickets for a client's resumption.
enum Kernel {
    Client(KernelConnection<ClientConnectionData>),
    Server(KernelConnection<ServerConnectionData>),
}

impl Kernel {
    /// The next traffic secret of one direction (TLS 1.3 key update).
    fn update(&mut self, transmit: bool) -> core::result::Result<(u64, ConnectionTrafficSecrets), rustls::Error> {
        match (self, transmit) {
            (Kernel::Client(k), true) => k.update_tx_secret(),
            (Kernel::Client(k), false) => k.update_rx_secret(),
            (Kernel::Server(k), true) => k.update_tx_secret(),
            (Kernel::Server(k), false) => k.update_rx_secret(),
        }
    }
}

/// Records sent under one key before a TLS 1.3 key update (AES-GCM's limit is some
/// 2^24.5 records; rustls updates before it too). A TLS 1.2 session that reaches it
/// ends (TLS 1.2 has no key update; rustls closes it there as well).
const KEY_UPDATE_AT: u64 = 1 << 23;
/// The most body a record received may have: 2^14 bytes of plaintext plus the most
/// a suite adds (TLS 1.3: 256; TLS 1.2: 2048).
const MAX_BODY_TLS13: usize = MAX_FRAGMENT + 256;
const MAX_BODY_TLS12: usize = MAX_FRAGMENT + 2048;

/// Alert descriptions sent.
const CLOSE_NOTIFY: u8 = 0;
const UNEXPECTED_MESSAGE: u8 = 10;
const BAD_RECORD_MAC: u8 = 20;
const RECORD_OVERFLOW: u8 = 22;
const DECODE_ERROR: u8 = 50;

/// One TLS connection on a socket, its handshake done: the records are protected
/// here ([`record::Direction`]) with the keys rustls agreed on, in the session's own
/// buffers. One `recv` fills the input, every whole record in it is opened in place,
/// and the plaintext of its application data stays where it is (moved down only to
/// join what is not taken yet); a send seals its records into the output buffer.
pub struct Session {
    kernel: Kernel,
    tls13: bool,
    tx: record::Direction,
    rx: record::Direction,
    /// `input[start..pend]`: plaintext not taken yet; `input[raw..have]`: records
    /// not opened yet (the start of one, in part); `pend <= raw`.
    input: Vec<u8>,
    start: usize,
    pend: usize,
    raw: usize,
    have: usize,
    output: Out,
    /// The records sent under one key before our key update ([`KEY_UPDATE_AT`]; the
    /// tests lower it to reach the update).
    key_update_at: u64,
    /// The peer closed: close_notify (a clean end) or the socket's end of stream.
    ended: bool,
    /// The last read left nothing held: the next answer may come alone, to be read in
    /// place ([`Session::read_into`]). Not at first: a TLS 1.3 server's session
    /// tickets (RFC 8446 section 4.6.1) come after the handshake, with the first
    /// answer or before it.
    alone: bool,
    /// A record that failed (decryption, a fatal alert): reported by the next read.
    failed: Option<Error>,
    role: Option<CString>,
    /// The socket's cookie (see `transport::socket_cookie`).
    cookie: u64,
}

impl Session {
    /// The session of a connection whose handshake completed on `fd`: rustls hands
    /// its traffic keys over (EMBTLS if it cannot: not expected), after it processed
    /// the records that came with the end of the handshake (session tickets,
    /// application data).
    pub fn new(conn: Conn, fd: i32) -> Result<Self> {
        let mut conn = conn;
        let role = conn
            .common()
            .peer_certificates()
            .and_then(|chain| chain.first())
            .and_then(|c| security::role(c))
            .and_then(|r| CString::new(r).ok());
        if conn.b.have > 0
            && let Err(e) = conn.advance()
        {
            conn.send_alert(fd);
            return Err(error_of(&e));
        }
        let tls13 = conn.common().protocol_version() == Some(rustls::ProtocolVersion::TLSv1_3);
        let Conn { peer, b } = conn;
        let (secrets, kernel) = match peer {
            Peer::Client(c) => c.dangerous_into_kernel_connection().map(|(s, k)| (s, Kernel::Client(k))),
            Peer::Server(s) => s.dangerous_into_kernel_connection().map(|(s, k)| (s, Kernel::Server(k))),
        }
        .map_err(|e| error_of(&e))?;
        let tx = record::Direction::new(secrets.tx.1, secrets.tx.0, tls13).ok_or(Error(EMBTLS))?;
        let rx = record::Direction::new(secrets.rx.1, secrets.rx.0, tls13).ok_or(Error(EMBTLS))?;
        // What rustls decrypted goes before the records held (once per session).
        let Buffers { mut input, have, mut output, plain, start, peer_closed } = b;
        let kept = plain.len() - start;
        if kept > 0 {
            input.splice(0..0, plain[start..].iter().copied());
        }
        // The handshake's records (certificates) made the buffers larger than a
        // transaction needs: an idle session keeps only what its transactions use
        // (once per session; a transaction then allocates nothing).
        let keep = INITIAL_INPUT.max(kept + have);
        if input.capacity() > keep {
            input.truncate(keep);
            input.shrink_to_fit();
        }
        output.trim(OUTPUT_KEPT);
        Ok(Session {
            kernel,
            tls13,
            tx,
            rx,
            input,
            start: 0,
            pend: kept,
            raw: kept,
            have: kept + have,
            output,
            key_update_at: KEY_UPDATE_AT,
            ended: peer_closed,
            alone: false,
            failed: None,
            role,
            cookie: super::socket_cookie(fd),
        })
    }

    /// The cookie of the socket the session runs on.
    pub fn cookie(&self) -> u64 {
        self.cookie
    }

    /// The role in the peer's certificate.
    pub fn role(&self) -> Option<&CStr> {
        self.role.as_deref()
    }

    /// Plaintext is there to take, or the end or a failure to report.
    #[inline]
    pub fn readable(&self) -> bool {
        self.start < self.pend || self.ended || self.failed.is_some()
    }

    /// The room a `recv` may fill: after the records held, the plaintext not taken
    /// and the records held moved down first when the end is reached, and the buffer
    /// grown when a record held in part still does not fit.
    fn input_room(&mut self) -> &mut [u8] {
        if self.start == self.pend && self.raw == self.have {
            (self.start, self.pend, self.raw, self.have) = (0, 0, 0, 0);
        }
        if self.have == self.input.len() {
            let kept = self.pend - self.start;
            self.input.copy_within(self.start..self.pend, 0);
            self.input.copy_within(self.raw..self.have, kept);
            self.have = kept + self.have - self.raw;
            (self.start, self.pend, self.raw) = (0, kept, kept);
            if self.have == self.input.len() {
                let record = record::record_len(&self.input[self.raw..self.have]).unwrap_or(0);
                let size = (self.raw + record).max(self.have + 1).max(INITIAL_INPUT);
                self.input.resize(size, 0);
            }
        }
        &mut self.input[self.have..]
    }

    /// One `recv` of records (with `flags`), opened into the plaintext. `Err` only
    /// for EAGAIN (nothing came) and EINTR; a failed socket or record is kept for the
    /// read to report.
    pub fn fill(&mut self, fd: i32, flags: i32) -> Result<()> {
        let received = super::recv(fd, self.input_room(), flags);
        if let Some(n) = self.received(received)? {
            self.have += n;
            self.open_records(fd);
        }
        Ok(())
    }

    /// What a `recv` of records brought: `Some(n)` bytes, or `None` when the stream
    /// ended or the socket failed (kept for the read to report); `Err` only for
    /// EAGAIN (nothing came) and EINTR.
    fn received(&mut self, received: Result<usize>) -> Result<Option<usize>> {
        match received {
            Ok(0) => self.ended = true,
            Ok(n) => return Ok(Some(n)),
            Err(e) if e.0 == libc::EAGAIN || e.0 == libc::EINTR => return Err(e),
            // A reset or another failure of the socket: reported by the read.
            Err(e) => self.failed = Some(e),
        }
        Ok(None)
    }

    /// Opens every whole record held, in order, until the peer's end or a failure
    /// (which only a record that is not application data brings).
    fn open_records(&mut self, fd: i32) {
        if self.readable_end() {
            return;
        }
        while let Some(len) = record::record_len(&self.input[self.raw..self.have]) {
            if len - 5 > if self.tls13 { MAX_BODY_TLS13 } else { MAX_BODY_TLS12 } {
                return self.fatal(fd, RECORD_OVERFLOW, rustls::Error::PeerSentOversizedRecord);
            }
            if self.raw + len > self.have {
                return;
            }
            let at = self.raw;
            self.raw += len;
            let (typ, range) = match self.rx.open(&mut self.input[at..at + len]) {
                Ok(opened) => opened,
                Err(record::BadRecord) => return self.fatal(fd, BAD_RECORD_MAC, rustls::Error::DecryptError),
            };
            let (from, to) = (at + range.start, at + range.end);
            if typ == record::APPLICATION_DATA {
                self.keep(from, to);
                continue;
            }
            let input = core::mem::take(&mut self.input);
            self.control(fd, typ, &input[from..to]);
            self.input = input;
            if self.readable_end() {
                return;
            }
        }
    }

    /// The plaintext at `input[from..to]` joins what is not taken yet.
    fn keep(&mut self, from: usize, to: usize) {
        if self.start == self.pend {
            (self.start, self.pend) = (from, to);
        } else {
            self.input.copy_within(from..to, self.pend);
            self.pend += to - from;
        }
    }

    /// A record that is not application data, its plaintext `plain`.
    fn control(&mut self, fd: i32, typ: u8, plain: &[u8]) {
        match typ {
            record::ALERT => self.alert(plain),
            record::HANDSHAKE => self.post_handshake(fd, plain),
            _ => self.unexpected(fd),
        }
    }

    /// An alert from the peer: close_notify ends the session; a warning (TLS 1.2) or
    /// user_canceled is passed over; anything else is the peer's refusal.
    fn alert(&mut self, plain: &[u8]) {
        let [level, description] = *plain else {
            self.failed = Some(Error(EMBTLS));
            return;
        };
        match description {
            CLOSE_NOTIFY => self.ended = true,
            90 => {}
            _ if level == 1 && !self.tls13 => {}
            _ => self.failed = Some(error_of(&rustls::Error::AlertReceived(AlertDescription::from(description)))),
        }
    }

    /// Handshake messages after the handshake (TLS 1.3): session tickets (a client
    /// gives them to rustls for resumption) and key updates. Each must be whole in
    /// its record (rustls and OpenSSL send them so).
    fn post_handshake(&mut self, fd: i32, plain: &[u8]) {
        if !self.tls13 {
            // A TLS 1.2 HelloRequest: renegotiation is not supported, the request is
            // passed over (as rustls does); anything else is unexpected.
            if plain != [0, 0, 0, 0] {
                self.unexpected(fd);
            }
            return;
        }
        let mut at = 0;
        while at < plain.len() {
            let Some(&[typ, a, b, c]) = plain.get(at..at + 4) else {
                return self.fatal(fd, DECODE_ERROR, rustls::Error::DecryptError);
            };
            let len = u32::from_be_bytes([0, a, b, c]) as usize;
            let body = at + 4..at + 4 + len;
            if body.end > plain.len() {
                return self.fatal(fd, DECODE_ERROR, rustls::Error::DecryptError);
            }
            at = body.end;
            let done = match (typ, &mut self.kernel) {
                (4, Kernel::Client(k)) => k.handle_new_session_ticket(&plain[body]),
                (24, _) if len == 1 => self.key_update(plain[body.start] == 1),
                _ => return self.unexpected(fd),
            };
            if let Err(e) = done {
                return self.fatal(fd, DECODE_ERROR, e);
            }
        }
    }

    /// The peer's key update: its next records come under the next key; when it asks,
    /// ours go under our next key too, after a key update of ours.
    fn key_update(&mut self, requested: bool) -> core::result::Result<(), rustls::Error> {
        let (seq, secrets) = self.kernel.update(false)?;
        self.rx = record::Direction::new(secrets, seq, true).ok_or(rustls::Error::EncryptError)?;
        if requested { self.update_keys() } else { Ok(()) }
    }

    /// Our key update: the message under the current key, then the next key.
    fn update_keys(&mut self) -> core::result::Result<(), rustls::Error> {
        self.seal(record::HANDSHAKE, &[24, 0, 0, 1, 0]);
        let (seq, secrets) = self.kernel.update(true)?;
        self.tx = record::Direction::new(secrets, seq, true).ok_or(rustls::Error::EncryptError)?;
        Ok(())
    }

    fn unexpected(&mut self, fd: i32) {
        self.fatal(fd, UNEXPECTED_MESSAGE, rustls::Error::General("unexpected message".into()))
    }

    /// A failure of the peer's records: our alert goes out if it can without
    /// waiting, the error is kept for the read.
    #[cold]
    fn fatal(&mut self, fd: i32, description: u8, error: rustls::Error) {
        self.seal(record::ALERT, &[2, description]);
        let _ = self.output.flush(fd);
        self.failed = Some(error_of(&error));
    }

    /// Seals `data` of type `typ` into records in the output.
    fn seal(&mut self, typ: u8, data: &[u8]) {
        let mut rest = data;
        while !rest.is_empty() {
            let (chunk, after) = rest.split_at(rest.len().min(MAX_FRAGMENT));
            let room = self.output.room(chunk.len() + self.tx.overhead());
            self.output.end += self.tx.seal(typ, chunk, room);
            rest = after;
        }
    }

    /// Seals application data, after a key update when the key has protected enough
    /// records (EMBTLS on TLS 1.2 then: the session ends).
    fn seal_data(&mut self, data: &[u8]) -> Result<()> {
        if self.tx.seq() >= self.key_update_at {
            if !self.tls13 {
                return Err(Error(EMBTLS));
            }
            self.update_keys().map_err(|e| error_of(&e))?;
        }
        self.seal(record::APPLICATION_DATA, data);
        Ok(())
    }

    /// Takes plaintext into `buf[at]` ([`Session::take`]), after one `recv` (with
    /// `flags`) of records when none is there to take. A read for `one` answer (a
    /// read that waits for it) when nothing at all is held and the last read left
    /// nothing either, the usual read of an answer, reads at most the record of a
    /// plaintext as long as `at`, into `buf` from [`room::BEFORE`] bytes before `at`
    /// (up to [`room::AFTER`] bytes after it): that record alone is opened in place
    /// there, its plaintext exactly at `at`, with no copy. Any other bytes move into
    /// the input and are opened there (what did not fit stays in the socket), and the
    /// next read takes all that is there. A read that is not for one answer (of what
    /// is queued: the event-driven client's, the runner's) reads all that is there
    /// into the input.
    pub fn read_into(&mut self, fd: i32, flags: i32, buf: &mut [u8], at: Range<usize>, one: bool) -> Result<usize> {
        if !self.readable() {
            if one && self.alone && self.raw == self.have && at.start >= room::BEFORE {
                return self.read_direct(fd, flags, buf, at);
            }
            self.fill(fd, flags)?;
        }
        let taken = self.take(&mut buf[at]);
        self.alone = self.start == self.pend && self.raw == self.have;
        taken
    }

    /// [`Session::read_into`] when nothing is held.
    fn read_direct(&mut self, fd: i32, flags: i32, buf: &mut [u8], at: Range<usize>) -> Result<usize> {
        let lo = at.start - room::BEFORE;
        let hi = buf.len().min(at.end + self.rx.overhead() - room::BEFORE);
        let Some(n) = self.received(super::recv(fd, &mut buf[lo..hi], flags))? else {
            return self.take(&mut buf[at]);
        };
        if record::record_len(&buf[lo..lo + n]) == Some(n) {
            match self.rx.open(&mut buf[lo..lo + n]) {
                Ok((record::APPLICATION_DATA, range)) if !range.is_empty() => {
                    // The plaintext starts right after the header: at `at`.
                    debug_assert_eq!(range.start, room::BEFORE);
                    return Ok(range.len());
                }
                Ok((record::APPLICATION_DATA, _)) => {}
                Ok((typ, range)) => self.control(fd, typ, &buf[lo + range.start..lo + range.end]),
                Err(record::BadRecord) => self.fatal(fd, BAD_RECORD_MAC, rustls::Error::DecryptError),
            }
            return self.take(&mut buf[at]);
        }
        // Not one whole record: the bytes go into the input (empty: `input_room` starts
        // it at 0, with room for more than a record here), to be opened there.
        self.input_room()[..n].copy_from_slice(&buf[lo..lo + n]);
        self.have = n;
        self.alone = false;
        self.open_records(fd);
        self.take(&mut buf[at])
    }

    /// Copies plaintext into `room` without taking it.
    #[inline]
    pub fn peek(&self, room: &mut [u8]) -> usize {
        let avail = &self.input[self.start..self.pend];
        let n = avail.len().min(room.len());
        room[..n].copy_from_slice(&avail[..n]);
        n
    }

    /// Takes plaintext into `room`: `Ok(0)` at the peer's end, `Err` for a failed
    /// record, EAGAIN when nothing is there.
    #[inline]
    pub fn take(&mut self, room: &mut [u8]) -> Result<usize> {
        let n = self.peek(room);
        if n > 0 {
            self.start += n;
            return Ok(n);
        }
        if let Some(e) = self.failed {
            return Err(e);
        }
        if self.ended { Ok(0) } else { Err(Error(libc::EAGAIN)) }
    }

    /// Plaintext received and not taken yet: the rest of a TLS record that carried
    /// more than the request or response read from it, and the records read with it.
    pub fn pending(&self) -> usize {
        self.pend - self.start
    }

    /// The peer ended the session, or a record failed.
    pub fn readable_end(&self) -> bool {
        self.ended || self.failed.is_some()
    }

    /// Drops the plaintext not taken (a flush); returns its length.
    pub fn discard(&mut self) -> usize {
        let n = self.pending();
        self.start = self.pend;
        n
    }

    /// Sends `data` as application data, waiting for room up to `timeout` (from the
    /// first wait: microseconds after the call, the time of a seal and a `send`).
    pub fn send(&mut self, fd: i32, data: &[u8], timeout: Timeout, stopping: &dyn Fn() -> bool) -> Result<usize> {
        let mut deadline = None;
        if self.output.waiting() {
            self.output.flush_within(fd, timeout, &mut deadline, stopping)?;
        }
        self.seal_data(data)?;
        self.output.flush_within(fd, timeout, &mut deadline, stopping)?;
        Ok(data.len())
    }

    /// TLS data waits to go out.
    pub fn wants_write(&self) -> bool {
        self.output.waiting()
    }

    /// Sends `plain` (taken from the vector) as application data, as far as the
    /// socket takes it without waiting: true when all is out.
    pub fn send_without_waiting(&mut self, fd: i32, plain: &mut Vec<u8>) -> Result<bool> {
        if !plain.is_empty() {
            self.seal_data(plain)?;
            plain.clear();
        }
        self.output.flush(fd)
    }

    /// Sends close_notify, without waiting.
    pub fn close(&mut self, fd: i32) {
        if let Ok(true) = self.output.flush(fd) {
            self.seal(record::ALERT, &[1, CLOSE_NOTIFY]);
            let _ = self.output.flush(fd);
        }
    }
}

/// The application's authorization callback (`modbus_set_tls_authorization`), as the
/// C layer wraps it: given the peer's role, the unit id, the function code, an
/// address and a count, true allows.
pub type Authorize = Arc<dyn Fn(Option<&CStr>, u8, u8, u16, u16) -> bool + Send + Sync>;

/// A context's TLS state: its settings, its authorization callback, and the
/// sessions of the sockets it connected or accepted that are not current (a server
/// that serves many clients on one context finds each client's session again when
/// `modbus_set_socket` makes its socket current: see `line::Line::adopt`).
#[derive(Default)]
pub struct Tls {
    pub settings: TlsSettings,
    pub authorize: Option<Authorize>,
    parked: HashMap<i32, Box<Session>>,
}

impl Tls {
    /// Keeps the session of `fd`, which stops being current.
    pub fn park(&mut self, fd: i32, session: Box<Session>) {
        self.parked.insert(fd, session);
    }

    /// The session parked for `fd`, when `fd` is still the socket it ran on (its
    /// cookie tells; a session of an earlier socket with the same number is dropped).
    pub fn unpark(&mut self, fd: i32) -> Option<Box<Session>> {
        let session = self.parked.remove(&fd)?;
        (session.cookie() == super::socket_cookie(fd)).then_some(session)
    }

    /// Drops the session parked for `fd`: that number is a new socket's now.
    pub fn forget(&mut self, fd: i32) {
        self.parked.remove(&fd);
    }
}

#[cfg(test)]
#[path = "tls_session_tests.rs"]
mod session_tests;

#[cfg(test)]
mod tests {
    use super::*;

    /// The decisions made before any decryption (decryption itself: the `password`
    /// scenario of c-tests/suites/tls.sh, with keys openssl encrypts at test time).
    #[test]
    fn which_keys_need_a_password() {
        let encrypted = b"-----BEGIN ENCRYPTED PRIVATE KEY-----\nMAA=\n-----END ENCRYPTED PRIVATE KEY-----\n";
        assert_eq!(private_key(encrypted, None).err(), Some(Error(EMBTLSPASSWORD)));
        // Not a PKCS#8 EncryptedPrivateKeyInfo: refused as unreadable, not as a password.
        assert_eq!(private_key(encrypted, Some(b"secret")).err(), Some(Error::INVALID));
        // No END line.
        assert_eq!(private_key(&encrypted[..40], Some(b"secret")).err(), Some(Error::INVALID));
        let legacy = b"-----BEGIN EC PRIVATE KEY-----\nProc-Type: 4,ENCRYPTED\nDEK-Info: AES-256-CBC,00\n\nMAA=\n-----END EC PRIVATE KEY-----\n";
        assert_eq!(private_key(legacy, Some(b"secret")).err(), Some(Error::INVALID));
        assert_eq!(private_key(legacy, None).err(), Some(Error::INVALID));
        assert_eq!(private_key(b"", None).err(), Some(Error::INVALID));
    }

    /// A key file's parameters must not make decryption take hours or more memory
    /// than there is (an allocation failure would abort the process), nor reach a
    /// panic in the KDF (scrypt with N < 2).
    #[test]
    fn hostile_key_parameters_are_refused_before_decryption() {
        use pkcs8::pkcs5::{EncryptionScheme, pbes2};
        let iv = [0u8; 16];
        let scrypt = |n: u64, r: u16, p: u16| {
            EncryptionScheme::Pbes2(pbes2::Parameters {
                kdf: pbes2::Kdf::Scrypt(pbes2::ScryptParams {
                    salt: b"salt",
                    cost_parameter: n,
                    block_size: r,
                    parallelization: p,
                    key_length: None,
                }),
                encryption: pbes2::EncryptionScheme::Aes256Cbc { iv: &iv },
            })
        };
        let pbkdf2 = |iterations: u32| {
            EncryptionScheme::Pbes2(pbes2::Parameters {
                kdf: pbes2::Kdf::Pbkdf2(pbes2::Pbkdf2Params {
                    salt: b"salt",
                    iteration_count: iterations,
                    key_length: None,
                    prf: pbes2::Pbkdf2Prf::HmacWithSha256,
                }),
                encryption: pbes2::EncryptionScheme::Aes256Cbc { iv: &iv },
            })
        };
        // What openssl writes.
        assert!(affordable(&scrypt(16384, 8, 1)));
        assert!(affordable(&pbkdf2(2048)));
        assert!(affordable(&pbkdf2(600_000)));
        // 1 PiB, 0, not a power of two, no block, too many passes.
        assert!(!affordable(&scrypt(1 << 40, 8, 1)));
        assert!(!affordable(&scrypt(0, 8, 1)));
        assert!(!affordable(&scrypt(1, 8, 1)));
        assert!(!affordable(&scrypt(3000, 8, 1)));
        assert!(!affordable(&scrypt(16384, 0, 1)));
        assert!(!affordable(&scrypt(16384, 8, 0)));
        assert!(!affordable(&scrypt(16384, 8, 1000)));
        assert!(!affordable(&scrypt(1 << 62, 1 << 15, 1)));
        assert!(!affordable(&pbkdf2(u32::MAX)));
        assert!(!affordable(&pbkdf2(0)));
    }
}
