#pragma once
/// @file stop_signal.hpp
/// One process-wide stop request, set by SIGINT / SIGTERM, for everything that must react to
/// Ctrl-C: devices send zero force at once (FalconDevice checks it every tick) and sessions end
/// between frames (`hapticloud explore`, `falcon-check`). One flag and one handler, so that
/// installing it twice (a device and a session) never replaces one reaction with the other.

namespace hc::haptics {

/// Installs SIGINT and SIGTERM handlers that only set the flag (async-signal-safe).
/// Idempotent. Real-time: no. Errors: none (a refused sigaction leaves the default handler).
void install_stop_signal_handlers();
/// True once SIGINT/SIGTERM arrived or request_stop() was called. Real-time: yes (one load).
bool stop_requested() noexcept;
/// Sets the flag by hand (tests, an app's own shutdown path). Real-time: yes.
void request_stop() noexcept;
/// Clears the flag (before a new session). Real-time: yes.
void clear_stop_request() noexcept;

}  // namespace hc::haptics
