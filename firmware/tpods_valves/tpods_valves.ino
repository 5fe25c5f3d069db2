// TPODS valve controller, serial protocol v1 (docs/valve-protocol.md).
// Reference sketch for an Arduino-class board (Uno, Nano, Mega, Leonardo): software PWM
// at 1-100 Hz on N_CH digital pins driving the solenoid valve drivers (MOSFETs).
// Untested on hardware: the host side is tested against bench/emulators/valves.py.

#include <Arduino.h>
#include <stdlib.h>
#include <string.h>

#define FIRMWARE "1.0"
#define N_CH 4
static const uint8_t PINS[N_CH] = {3, 5, 6, 9};   // valve driver gates
#define LINE_MAX 256

static float duty[N_CH];              // percent, 0 = closed
static float freqHz = 10.0;
static unsigned long wdtMs = 0;       // 0 = disabled
static unsigned long lastCmdMs = 0;
static char line[LINE_MAX + 1];
static size_t lineLen = 0;
static bool overflow = false;

static void allOff() {
  for (int i = 0; i < N_CH; i++) { duty[i] = 0; digitalWrite(PINS[i], LOW); }
}

// Parse a decimal number; false if the token is not entirely a number.
static bool parseNum(const char *tok, float *out) {
  if (tok == NULL || *tok == 0) return false;
  char *end;
  double v = strtod(tok, &end);
  if (*end != 0) return false;
  *out = (float)v;
  return true;
}

static void printDuty(float d) {
  if (d == (long)d) Serial.print((long)d); else Serial.print(d, 3);
}

static void handle(char *cmd) {
  char *argv[N_CH + 2];
  int argc = 0;
  for (char *tok = strtok(cmd, " \t"); tok && argc < N_CH + 2; tok = strtok(NULL, " \t")) argv[argc++] = tok;
  if (strtok(NULL, " \t") != NULL) { Serial.println("ERR too many arguments"); return; }
  if (argc == 0) { Serial.println("ERR empty command"); return; }
  const char *c = argv[0];
  float v;
  if (!strcmp(c, "ID?") && argc == 1) {
    Serial.print("TPODS-VALVES " FIRMWARE " "); Serial.println(N_CH);
  } else if (!strcmp(c, "PING") && argc == 1) {
    Serial.println("PONG");
  } else if (!strcmp(c, "STATE?") && argc == 1) {
    Serial.print("STATE");
    for (int i = 0; i < N_CH; i++) { Serial.print(' '); printDuty(duty[i]); }
    Serial.println();
  } else if (!strcmp(c, "OFF") && argc == 1) {
    allOff(); Serial.println("OK");
  } else if (!strcmp(c, "FREQ") && argc == 2) {
    if (!parseNum(argv[1], &v)) Serial.println("ERR bad number");
    else if (v < 1 || v > 100) Serial.println("ERR frequency must be 1-100 Hz");
    else { freqHz = v; Serial.println("OK"); }
  } else if (!strcmp(c, "WDT") && argc == 2) {
    if (!parseNum(argv[1], &v) || v != (long)v) Serial.println("ERR bad number");
    else if (v < 0 || v > 600000) Serial.println("ERR watchdog must be 0-600000 ms");
    else { wdtMs = (unsigned long)v; Serial.println("OK"); }
  } else if (!strcmp(c, "DUTY") && argc == 3) {
    float ch;
    if (!parseNum(argv[1], &ch) || !parseNum(argv[2], &v)) Serial.println("ERR bad number");
    else if (ch != (long)ch || ch < 1 || ch > N_CH) { Serial.print("ERR channel must be 1-"); Serial.println(N_CH); }
    else if (v < 0 || v > 100) Serial.println("ERR duty must be 0-100");
    else { duty[(int)ch - 1] = v; Serial.println("OK"); }
  } else if (!strcmp(c, "DUTY*") && argc == N_CH + 1) {
    float vals[N_CH];
    for (int i = 0; i < N_CH; i++) {
      if (!parseNum(argv[i + 1], &vals[i])) { Serial.println("ERR bad number"); return; }
      if (vals[i] < 0 || vals[i] > 100) { Serial.println("ERR duty must be 0-100"); return; }
    }
    for (int i = 0; i < N_CH; i++) duty[i] = vals[i];
    Serial.println("OK");
  } else {
    Serial.println("ERR unknown command");
  }
}

void setup() {
  for (int i = 0; i < N_CH; i++) pinMode(PINS[i], OUTPUT);
  allOff();                          // closed at power-up, watchdog disabled
  Serial.begin(115200);
  lastCmdMs = millis();
}

void loop() {
  while (Serial.available()) {
    char ch = (char)Serial.read();
    if (ch == '\r') continue;
    if (ch == '\n') {
      lastCmdMs = millis();          // any line feeds the watchdog
      if (overflow) Serial.println("ERR line too long");
      else { line[lineLen] = 0; handle(line); }
      lineLen = 0; overflow = false;
    } else if (lineLen < LINE_MAX) {
      line[lineLen++] = ch;
    } else {
      overflow = true;
    }
  }
  unsigned long now = millis();
  if (wdtMs > 0 && now - lastCmdMs > wdtMs) allOff();
  // software PWM: valve i open for the first duty[i] % of every period
  unsigned long periodUs = (unsigned long)(1e6 / freqHz);
  unsigned long phase = micros() % periodUs;
  for (int i = 0; i < N_CH; i++) {
    bool open = duty[i] > 0 && phase < (unsigned long)(duty[i] / 100.0 * periodUs);
    digitalWrite(PINS[i], open ? HIGH : LOW);
  }
}
