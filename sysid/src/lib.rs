//! System identification and analyses on actuation logs.
