//! A simulated FANUC controller with the Modbus/TCP option: a Modbus server whose writes land in
//! the robot's input words and whose reads return its output words, that keeps at most four
//! connections (a fifth closes the oldest and raises an alarm) and closes every connection after
//! an idle spell; plus a task playing the reference TP program.

#![allow(dead_code)]

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use lfi_bridge::modbus::frame;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

/// A part as the TP program decoded it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Picked {
    pub seq: u16,
    pub type_id: u16,
    pub face: u16,
    pub angle: i32,
    pub x: i32,
    pub y: i32,
    pub confidence: u16,
    /// USER_DATA from words 8-9 (high word first).
    pub user_data: u32,
}

#[derive(Debug)]
pub struct State {
    pub inputs: Vec<u16>,
    pub outputs: Vec<u16>,
    pub alarms: u32,
    pub connections: u32,
    pub idle_closes: u32,
    pub last_request: tokio::time::Instant,
    /// Every FC16/FC6 write, in order: (address, words).
    pub writes: Vec<(u16, Vec<u16>)>,
}

pub struct Fanuc {
    pub addr: SocketAddr,
    pub state: Arc<Mutex<State>>,
    stop: CancellationToken,
    idle: Duration,
}

const WORDS: usize = 64;

/// The TP program's conversion of an unsigned group input to a signed value.
pub fn signed(gi: u16) -> i32 {
    let gi = gi as i32;
    gi - (gi / 32768) * 65536
}

impl Fanuc {
    pub async fn start(idle: Duration) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let state = Arc::new(Mutex::new(State {
            inputs: vec![0; WORDS],
            outputs: vec![0; WORDS],
            alarms: 0,
            connections: 0,
            idle_closes: 0,
            last_request: tokio::time::Instant::now(),
            writes: Vec::new(),
        }));
        let stop = CancellationToken::new();
        tokio::spawn(serve(listener, state.clone(), stop.clone(), idle));
        Fanuc { addr, state, stop, idle }
    }

    /// A controller reboot: every connection drops, the port is closed for `down`, and the
    /// registers come back zeroed.
    pub async fn restart(&mut self, down: Duration) {
        self.stop.cancel();
        tokio::time::sleep(down).await;
        {
            let mut s = self.state.lock().unwrap();
            s.inputs.iter_mut().for_each(|w| *w = 0);
            s.outputs.iter_mut().for_each(|w| *w = 0);
        }
        let listener = loop {
            match TcpListener::bind(self.addr).await {
                Ok(l) => break l,
                Err(_) => tokio::time::sleep(Duration::from_millis(20)).await,
            }
        };
        self.stop = CancellationToken::new();
        tokio::spawn(serve(listener, self.state.clone(), self.stop.clone(), self.idle));
    }

    pub fn set_output(&self, offset: usize, v: u16) {
        self.state.lock().unwrap().outputs[offset] = v;
    }
    pub fn output(&self, offset: usize) -> u16 {
        self.state.lock().unwrap().outputs[offset]
    }
    pub fn inputs(&self) -> Vec<u16> {
        self.state.lock().unwrap().inputs.clone()
    }

    pub fn stop(&self) {
        self.stop.cancel();
    }
}

async fn serve(listener: TcpListener, state: Arc<Mutex<State>>, stop: CancellationToken, idle: Duration) {
    let mut conns: Vec<CancellationToken> = Vec::new();
    let mut idle_check = tokio::time::interval(Duration::from_millis(20));
    loop {
        tokio::select! {
            _ = stop.cancelled() => {
                conns.iter().for_each(|c| c.cancel());
                return;
            }
            _ = idle_check.tick() => {
                let quiet = state.lock().unwrap().last_request.elapsed() > idle;
                conns.retain(|c| !c.is_cancelled());
                if quiet && !conns.is_empty() {
                    conns.iter().for_each(|c| c.cancel());
                    conns.clear();
                    state.lock().unwrap().idle_closes += 1;
                }
            }
            a = listener.accept() => {
                let Ok((stream, _)) = a else { continue };
                conns.retain(|c| !c.is_cancelled());
                if conns.len() >= 4 {
                    conns.remove(0).cancel();
                    state.lock().unwrap().alarms += 1;
                }
                let token = CancellationToken::new();
                conns.push(token.clone());
                {
                    let mut s = state.lock().unwrap();
                    s.connections += 1;
                    s.last_request = tokio::time::Instant::now();
                }
                tokio::spawn(session(stream, state.clone(), token));
            }
        }
    }
}

async fn session(mut stream: tokio::net::TcpStream, state: Arc<Mutex<State>>, token: CancellationToken) {
    let mut buf = Vec::new();
    let mut chunk = [0u8; 512];
    loop {
        while let Ok(Some(adu)) = frame::decode(&mut buf) {
            let pdu = &adu.pdu;
            let be = |i: usize| u16::from_be_bytes([pdu[i], pdu[i + 1]]);
            let mut out = Vec::new();
            {
                let mut s = state.lock().unwrap();
                s.last_request = tokio::time::Instant::now();
                match pdu[0] {
                    0x03 | 0x04 => {
                        let (a, n) = (be(1) as usize, be(3) as usize);
                        out.push(pdu[0]);
                        out.push((2 * n) as u8);
                        for i in 0..n {
                            out.extend_from_slice(&s.outputs[a + i].to_be_bytes());
                        }
                    }
                    0x06 => {
                        let (a, v) = (be(1), be(3));
                        s.inputs[a as usize] = v;
                        s.writes.push((a, vec![v]));
                        out.extend_from_slice(&pdu[..5]);
                    }
                    0x10 => {
                        let (a, n) = (be(1) as usize, be(3) as usize);
                        let words: Vec<u16> = (0..n).map(|i| be(6 + 2 * i)).collect();
                        s.inputs[a..a + n].copy_from_slice(&words);
                        s.writes.push((a as u16, words));
                        out.extend_from_slice(&pdu[..5]);
                    }
                    fc => out.extend_from_slice(&[fc | 0x80, 1]),
                }
            }
            let mut resp = Vec::new();
            resp.extend_from_slice(&adu.transaction.to_be_bytes());
            resp.extend_from_slice(&[0, 0]);
            resp.extend_from_slice(&((out.len() + 1) as u16).to_be_bytes());
            resp.push(adu.unit);
            resp.extend_from_slice(&out);
            if stream.write_all(&resp).await.is_err() {
                return;
            }
        }
        tokio::select! {
            _ = token.cancelled() => return,
            r = stream.read(&mut chunk) => match r {
                Ok(0) | Err(_) => return,
                Ok(n) => buf.extend_from_slice(&chunk[..n]),
            }
        }
    }
}

/// How the simulated robot program behaves.
#[derive(Debug, Clone, Copy)]
pub struct Program {
    pub input_at: usize,
    pub output_at: usize,
    pub pick: Duration,
}

/// Plays the reference TP program (`docs/fanuc/LFI_PICK.LS`): wait for a DATA_SEQ other than
/// the last one taken, read and convert the words, pick, acknowledge. The last sequence taken
/// lives in a retained register (R[1] on the controller) and is written back to ACK_SEQ, so a
/// controller restart, which zeroes the I/O words, does not make a taken part look new.
/// Returns the parts picked, in order, when `stop` is cancelled.
pub async fn tp_program(fanuc: Arc<Mutex<State>>, prog: Program, stop: CancellationToken) -> Vec<Picked> {
    let mut picked = Vec::new();
    let mut last: u16 = 0;
    {
        let mut s = fanuc.lock().unwrap();
        s.outputs[prog.output_at] = 1;
    }
    while !stop.is_cancelled() {
        let (seq, w, ready) = {
            let mut s = fanuc.lock().unwrap();
            s.outputs[prog.output_at + 1] = last;
            let w = s.inputs[prog.input_at..prog.input_at + 10].to_vec();
            (w[0], w, s.outputs[prog.output_at] & 1 != 0)
        };
        if ready && seq != 0 && seq != last {
            picked.push(Picked {
                seq,
                type_id: w[1],
                face: w[2],
                angle: signed(w[3]),
                x: signed(w[4]),
                y: signed(w[5]),
                confidence: w[6],
                user_data: ((w[8] as u32) << 16) | w[9] as u32,
            });
            tokio::time::sleep(prog.pick).await;
            last = seq;
            fanuc.lock().unwrap().outputs[prog.output_at + 1] = seq;
        }
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    picked
}

/// A robot cell for whole-appliance tests: a simulated controller running the reference TP
/// program, and the `[camera.robot]` table that points a camera at it.
pub struct Cell {
    pub fanuc: Fanuc,
    /// Input words start at word 10, output words at 30.
    pub robot_toml: String,
    stop: CancellationToken,
    program: tokio::task::JoinHandle<Vec<Picked>>,
}

impl Cell {
    pub const IN: u16 = 10;
    pub const OUT: u16 = 30;

    pub async fn start(pick: Duration) -> Self {
        let fanuc = Fanuc::start(Duration::from_secs(30)).await;
        let stop = CancellationToken::new();
        let prog = Program { input_at: Self::IN as usize, output_at: Self::OUT as usize, pick };
        let program = tokio::spawn(tp_program(fanuc.state.clone(), prog, stop.clone()));
        let robot_toml = format!(
            "[camera.robot]\naddress = \"{}\"\ninput_words_at = {}\noutput_words_at = {}\npoll_ms = 5\nack_timeout_s = 5",
            fanuc.addr,
            Self::IN,
            Self::OUT
        );
        Cell { fanuc, robot_toml, stop, program }
    }

    /// Waits until the robot program has acknowledged `n` parts (panics after `limit`).
    pub async fn until_acknowledged(&self, n: usize, limit: Duration) {
        let end = tokio::time::Instant::now() + limit;
        while (self.fanuc.output(Self::OUT as usize + 1) as usize) < n {
            assert!(tokio::time::Instant::now() < end, "the robot acknowledged {} of {n} parts", self.fanuc.output(Self::OUT as usize + 1));
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }

    /// Stops the program and the controller; the parts picked, in order.
    pub async fn picked(self) -> Vec<Picked> {
        self.stop.cancel();
        let picked = self.program.await.expect("the TP program ends");
        self.fanuc.stop();
        picked
    }
}
