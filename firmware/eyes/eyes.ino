// nod-hri robotic eyes: four hobby servos driven by framed, checksummed serial commands.
//
// Protocol: firmware/eyes/PROTOCOL.md (the driver is services/eyes/arduino.py; its tests run
// against a byte-level model of this sketch, tests/emulators/arduino_emulator.py).
//
//   frame = 0xA5 | cmd | len | payload[len] | crc8(cmd, len, payload)   (CRC-8/SMBUS)
//
// Board: any Arduino with the Servo library (Uno, Nano, Leonardo, Mega). Servo signal wires on
// pins 3, 5, 6, 9 (left pan, left tilt, right pan, right tilt); servo power from a separate
// 5-6 V supply whose ground is tied to the Arduino's GND.

#include <Servo.h>

static const uint32_t BAUD = 115200;
static const uint8_t N_SERVOS = 4;
static const uint8_t SERVO_PINS[N_SERVOS] = {3, 5, 6, 9};  // left pan, left tilt, right pan, right tilt
static const uint16_t MIN_PULSE_US = 500;   // hard limits, whatever the host sends
static const uint16_t MAX_PULSE_US = 2500;
static const uint16_t NEUTRAL_US = 1500;    // after reset: looking straight ahead

static const uint8_t SYNC = 0xA5;
static const uint8_t PROTOCOL_VERSION = 1;
static const uint8_t MAX_PAYLOAD = 16;
static const uint8_t CMD_PING = 0x01;
static const uint8_t CMD_SET_PULSES = 0x02;
static const uint8_t CMD_GET_PULSES = 0x03;
static const uint8_t REPLY = 0x80;
static const uint8_t NAK = 0x7F;
static const uint8_t NAK_BAD_CRC = 1;
static const uint8_t NAK_UNKNOWN = 2;
static const uint8_t NAK_BAD_LENGTH = 3;
static const uint16_t FRAME_TIMEOUT_MS = 50;  // a frame must arrive within this; else restart

Servo servos[N_SERVOS];
uint16_t pulses[N_SERVOS];

// Parser state.
enum State : uint8_t { WAIT_SYNC, READ_CMD, READ_LEN, READ_PAYLOAD, READ_CRC };
State state = WAIT_SYNC;
uint8_t cmd = 0, len = 0, got = 0;
uint8_t payload[MAX_PAYLOAD];
uint32_t frame_started_ms = 0;

uint8_t crc8_update(uint8_t crc, uint8_t byte) {
  crc ^= byte;
  for (uint8_t i = 0; i < 8; i++) {
    crc = (crc & 0x80) ? (uint8_t)((crc << 1) ^ 0x07) : (uint8_t)(crc << 1);
  }
  return crc;
}

void send_frame(uint8_t reply_cmd, const uint8_t *data, uint8_t n) {
  uint8_t crc = crc8_update(crc8_update(0, reply_cmd), n);
  Serial.write(SYNC);
  Serial.write(reply_cmd);
  Serial.write(n);
  for (uint8_t i = 0; i < n; i++) {
    Serial.write(data[i]);
    crc = crc8_update(crc, data[i]);
  }
  Serial.write(crc);
}

void send_nak(uint8_t code) { send_frame(NAK, &code, 1); }

void send_pulses(uint8_t reply_cmd) {
  uint8_t out[2 * N_SERVOS];
  for (uint8_t i = 0; i < N_SERVOS; i++) {
    out[2 * i] = pulses[i] & 0xFF;         // little endian
    out[2 * i + 1] = pulses[i] >> 8;
  }
  send_frame(reply_cmd, out, sizeof out);
}

void apply_pulse(uint8_t i, uint16_t us) {
  if (us < MIN_PULSE_US) us = MIN_PULSE_US;
  if (us > MAX_PULSE_US) us = MAX_PULSE_US;
  pulses[i] = us;
  servos[i].writeMicroseconds(us);
}

void handle_frame() {
  switch (cmd) {
    case CMD_PING: {
      const uint8_t info[2] = {PROTOCOL_VERSION, N_SERVOS};
      send_frame(CMD_PING | REPLY, info, 2);
      break;
    }
    case CMD_SET_PULSES:
      if (len != 2 * N_SERVOS) { send_nak(NAK_BAD_LENGTH); return; }
      for (uint8_t i = 0; i < N_SERVOS; i++) {
        apply_pulse(i, (uint16_t)payload[2 * i] | ((uint16_t)payload[2 * i + 1] << 8));
      }
      send_pulses(CMD_SET_PULSES | REPLY);  // echo what is applied, after clamping
      break;
    case CMD_GET_PULSES:
      send_pulses(CMD_GET_PULSES | REPLY);
      break;
    default:
      send_nak(NAK_UNKNOWN);
  }
}

void setup() {
  for (uint8_t i = 0; i < N_SERVOS; i++) {
    servos[i].attach(SERVO_PINS[i], MIN_PULSE_US, MAX_PULSE_US);
    apply_pulse(i, NEUTRAL_US);
  }
  Serial.begin(BAUD);
}

void loop() {
  if (state != WAIT_SYNC && millis() - frame_started_ms > FRAME_TIMEOUT_MS) {
    state = WAIT_SYNC;  // a torn frame: drop it and wait for the next sync byte
  }
  while (Serial.available() > 0) {
    uint8_t b = (uint8_t)Serial.read();
    switch (state) {
      case WAIT_SYNC:
        if (b == SYNC) { state = READ_CMD; frame_started_ms = millis(); }
        break;
      case READ_CMD:
        cmd = b;
        state = READ_LEN;
        break;
      case READ_LEN:
        len = b;
        got = 0;
        if (len > MAX_PAYLOAD) { send_nak(NAK_BAD_LENGTH); state = WAIT_SYNC; }
        else state = (len == 0) ? READ_CRC : READ_PAYLOAD;
        break;
      case READ_PAYLOAD:
        payload[got++] = b;
        if (got == len) state = READ_CRC;
        break;
      case READ_CRC: {
        uint8_t crc = crc8_update(crc8_update(0, cmd), len);
        for (uint8_t i = 0; i < len; i++) crc = crc8_update(crc, payload[i]);
        state = WAIT_SYNC;
        if (crc != b) send_nak(NAK_BAD_CRC);
        else handle_frame();
        break;
      }
    }
  }
}
