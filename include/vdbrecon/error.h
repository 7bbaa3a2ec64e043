// Error types. The library reports every failure by throwing one of these; messages say what
// went wrong, where (file, element, line) and, when there is one, a hint.
#pragma once

#include <stdexcept>
#include <string>

namespace vdbrecon {

/// Base of every vdbrecon exception.
class Error : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// A file could not be opened, read, written or renamed (the OS said no).
class IoError : public Error {
public:
    using Error::Error;
};

/// A file was readable but its contents are malformed, truncated or unsupported.
/// The message starts with the file name, e.g. "scan.ply: vertex 1204: truncated binary data".
class FormatError : public Error {
public:
    using Error::Error;
};

/// An option or argument is out of range or inconsistent (names the field and the value).
class InvalidArgument : public Error {
public:
    using Error::Error;
};

/// A computation could not produce a meaningful result (degenerate input, empty volume, ...).
class NumericalError : public Error {
public:
    using Error::Error;
};

}  // namespace vdbrecon
