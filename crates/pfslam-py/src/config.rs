//! The configuration from Python: `None`, TOML text or a dict of sections, read by
//! `Config::from_toml_str` so that unknown keys and bad values fail as in `pfslam run
//! --config`.

use crate::errors::{ConfigError, config_error};
use pfslam::Config;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use std::path::Path;

/// The configuration `obj` gives over the defaults, checked.
pub fn config_from(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Config> {
    let config = match obj {
        None => Config::default(),
        Some(o) if o.is_none() => Config::default(),
        Some(o) if o.is_instance_of::<PyString>() => {
            let text: String = o.extract()?;
            parse(&text, "<config>")?
        }
        Some(o) if o.is_instance_of::<PyDict>() => {
            let table = match to_toml(o)? {
                toml::Value::Table(t) => t,
                _ => return Err(ConfigError::new_err("config: a dict of sections")),
            };
            let text = toml::to_string(&table).map_err(|e| config_error(&e))?;
            parse(&text, "<config dict>")?
        }
        Some(o) => {
            let kind = o.get_type().name()?;
            return Err(ConfigError::new_err(format!(
                "config: None, TOML text or a dict, not {kind}"
            )));
        }
    };
    config.validate().map_err(|e| config_error(&e))?;
    Ok(config)
}

fn parse(text: &str, name: &str) -> PyResult<Config> {
    Config::from_toml_str(text, Path::new(name)).map_err(|e| config_error(&e))
}

/// A Python value as TOML (bool before int: `bool` is an `int` in Python).
fn to_toml(o: &Bound<'_, PyAny>) -> PyResult<toml::Value> {
    if o.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(o.extract()?));
    }
    if o.is_instance_of::<PyInt>() {
        return Ok(toml::Value::Integer(o.extract()?));
    }
    if o.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(o.extract()?));
    }
    if o.is_instance_of::<PyString>() {
        return Ok(toml::Value::String(o.extract()?));
    }
    if let Ok(d) = o.cast::<PyDict>() {
        let mut table = toml::Table::new();
        for (k, v) in d.iter() {
            let key: String = k
                .extract()
                .map_err(|_| ConfigError::new_err(format!("config: key {k} is not a string")))?;
            table.insert(key, to_toml(&v)?);
        }
        return Ok(toml::Value::Table(table));
    }
    if o.is_instance_of::<PyList>() || o.is_instance_of::<PyTuple>() {
        let items: PyResult<Vec<toml::Value>> = o.try_iter()?.map(|v| to_toml(&v?)).collect();
        return Ok(toml::Value::Array(items?));
    }
    let kind = o.get_type().name()?;
    Err(ConfigError::new_err(format!(
        "config: a value of type {kind} has no TOML form (leave the key out for its default)"
    )))
}
